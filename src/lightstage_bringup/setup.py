"""ament_python package: installs with pip into a venv and builds unchanged with colcon."""
from setuptools import find_packages, setup

package_name = 'lightstage_bringup'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    include_package_data=True,
    # the operator's page (lightstage web): plain HTML / CSS / JS served from the package
    package_data={package_name: ['web_static/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', ['config/lightstage.yaml', 'config/real_rig.yaml', 'config/acquisition_sim.yaml',
                                               'config/foxglove_layout.json']),
        ('share/' + package_name + '/launch', ['launch/lightstage.launch.py']),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='lightstage maintainers',
    maintainer_email='maintainers@lightstage.invalid',
    description='Bring-up of the whole graph: the lightstage CLI, lightstage up, launch file, configuration (the simulated stage and a real rig), the demo.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'lightstage = lightstage_bringup.cli:main',
        ],
    },
)

"""ament_python package: installs with pip into a venv and builds unchanged with colcon."""
from setuptools import find_packages, setup

package_name = 'lightstage_graph'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    include_package_data=True,
    package_data={'lightstage_graph': ['config/*.xml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', ['lightstage_graph/config/fastdds_profile.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='lightstage maintainers',
    maintainer_email='maintainers@lightstage.invalid',
    description='The light stage graph contract: names, QoS, parameters, stamps, diagnostics, '
                'ROS environment, node start/stop, frame matching, stage and graph clients.',
    license='Apache-2.0',
)

"""ament_python package: installs with pip into a venv and builds unchanged with colcon."""
from setuptools import find_packages, setup

package_name = 'lightstage_physics'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    include_package_data=True,
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='lightstage maintainers',
    maintainer_email='maintainers@lightstage.invalid',
    description='The stage physics without hardware or ROS: rig conventions, capture format, scene models, rendering (NumPy and JAX), noise model and its fit, synthetic captures and flat objects, output files.',
    license='Apache-2.0',
)

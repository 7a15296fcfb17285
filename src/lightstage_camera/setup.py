"""ament_python package: installs with pip into a venv and builds unchanged with colcon."""
from setuptools import find_packages, setup

package_name = 'lightstage_camera'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    include_package_data=True,
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        # `ros2 run lightstage_camera EXE` looks for an executable at <prefix>/lib/<pkg>/EXE;
        # pip puts console_scripts in bin/, so small wrappers are installed there as data.
        ('lib/' + package_name, ['scripts/camera_node', 'scripts/acquisition_node'])
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='lightstage maintainers',
    maintainer_email='maintainers@lightstage.invalid',
    description='Camera hardware and acquisition: the camera node and its backends (simulated, pypylon, Aravis), trigger pairing, and the acquisition node (model capture, noise calibration). The physics it renders and records is lightstage_physics.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'lightstage-camera-node = lightstage_camera.camera_node:main',
            'lightstage-acquisition-node = lightstage_camera.acquisition_node:main',
        ],
    },
)

"""ament_python package: installs with pip into a venv and builds unchanged with colcon."""
from setuptools import find_packages, setup

package_name = 'lightstage_recording'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    include_package_data=True,
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        # `ros2 run lightstage_recording recorder|player` look in <prefix>/lib/<pkg>/; pip puts
        # console_scripts in bin/, so small wrappers are installed there as data.
        ('lib/' + package_name, ['scripts/recorder', 'scripts/player']),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='lightstage maintainers',
    maintainer_email='maintainers@lightstage.invalid',
    description='Recording and replay: rosbag2-compatible MCAP bags, the recorder and player '
                'nodes, `lightstage record|play|bag`.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'lightstage-recorder = lightstage_recording.recorder_node:main',
            'lightstage-player = lightstage_recording.player_node:main',
        ],
    },
)

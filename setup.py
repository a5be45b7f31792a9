"""Packaging for det_sim_ros (ament_python layout; also installs with plain pip)."""

from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'det_sim_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        (os.path.join('share', package_name), ['package.xml']),
        (os.path.join('share', package_name, 'config'), sorted(glob('config/*.yaml'))),
        # `ros2 run det_sim_ros sim_node` looks only in <prefix>/lib/det_sim_ros
        (os.path.join('lib', package_name), ['scripts/sim_node']),
    ],
    python_requires='>=3.10',
    install_requires=[
        'setuptools',
        'numpy>=1.26,<3',
        'scipy>=1.11,<2',
        'numba>=0.60,<1',
        'pyyaml>=6.0,<7',
        'mcap>=1.6,<2',
        'mcap-ros2-support>=0.5,<1',
        'ros-jazzy-rclpy>=7.1,<8',
        'ros-jazzy-common-interfaces>=5.3,<6',
        'ros-jazzy-rmw-fastrtps-cpp>=8.4,<9',
    ],
    extras_require={
        'test': ['pytest>=7', 'hypothesis>=6', 'rosbags>=0.10', 'control>=0.10'],
        'plots': ['matplotlib>=3.7'],
    },
    zip_safe=False,
    maintainer='det_sim_ros maintainers',
    maintainer_email='det-sim-ros@example.com',
    description='Dielectric elastomer transducer / buckled beam simulator with a ROS 2 node',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'sim_node = det_sim_ros.sim_node:main',
            'det_sim = det_sim_ros.cli:main',
            'det_sim_replay = det_sim_ros.replay:main',
        ],
        # the det_sim fixture (lockstep controller tests), available wherever this is installed
        'pytest11': ['det_sim = det_sim_ros.testing'],
    },
)

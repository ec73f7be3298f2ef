"""ament_python package sar_nav_node (also installable with pip; see setup.cfg)."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'sar_nav_node'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    package_data={package_name: ['config/*.yaml', 'py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        # Default params file: share/ for colcon users, package data for importlib.resources.
        ('share/' + package_name + '/config', glob(package_name + '/config/*.yaml')),
    ],
    # The PyPI names of the libraries the sources import (the ROS packages and the workspace's own
    # come from package.xml: rosdep / the ros-jazzy wheels); test/test_dependencies.py checks both.
    install_requires=['setuptools', 'numpy'],
    python_requires='>=3.10',
    zip_safe=False,
    maintainer='dpos developers',
    maintainer_email='maintainers@dpos.invalid',
    description='SINS/SAR/barometer navigation of the main POS ([Yan2016]: EKF, UKF, PF, RPF, MCMC-RPF).',
    license='MIT',
    entry_points={
        'console_scripts': [
            'sar_nav_node = sar_nav_node.node:main',
        ],
    },
)

"""ament_python package dpos_core (also installable with pip; see setup.cfg)."""

from setuptools import find_packages, setup

package_name = 'dpos_core'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    # Data read with importlib.resources (config/scenarios/*.yaml, config/aircraft/*.yaml).
    package_data={package_name: ['**/*.yaml', 'py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    # The PyPI names of the libraries the sources import (the ROS packages and the workspace's own
    # come from package.xml: rosdep / the ros-jazzy wheels); test/test_dependencies.py checks both.
    install_requires=['setuptools', 'numpy', 'scipy', 'numba', 'pyyaml'],
    # dpos-strapdown-demo plots its errors when matplotlib is installed
    extras_require={'plot': ['matplotlib']},
    python_requires='>=3.10',
    zip_safe=False,
    maintainer='dpos developers',
    maintainer_email='maintainers@dpos.invalid',
    description='Pure navigation and estimation algorithms of the distributed POS (numpy/scipy/numba; no ROS imports).',
    license='MIT',
    entry_points={
        'console_scripts': [
            'dpos-strapdown-demo = dpos_core.demo:main',
        ],
    },
)

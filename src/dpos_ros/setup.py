"""ament_python package dpos_ros (also installable with pip; see setup.cfg)."""

from setuptools import find_packages, setup

package_name = 'dpos_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    package_data={package_name: ['graphs/*.yaml', 'py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    # The PyPI names of the libraries the sources import (the ROS packages and the workspace's own
    # come from package.xml: rosdep / the ros-jazzy wheels); test/test_dependencies.py checks both.
    install_requires=['setuptools', 'numpy', 'numba', 'pyyaml', 'matplotlib', 'ruamel.yaml', 'rosbags', 'zstandard', 'lz4', 'tqdm'],
    # dpos-campaign's Dask engine: pip install 'dpos_ros[campaign]' (requirements-dev.txt has it);
    # cryptography: the local cluster's temporary TLS certificate (Security.temporary())
    extras_require={'campaign': ['dask', 'distributed', 'cryptography']},
    python_requires='>=3.10',
    zip_safe=False,
    maintainer='dpos developers',
    maintainer_email='maintainers@dpos.invalid',
    description='Shared ROS 2 glue of dpos: QoS profiles, parameter handling, node entry points.',
    license='MIT',
    entry_points={
        'console_scripts': [
            'dpos-sim = dpos_ros.cli.sim:main',
            'dpos-plot-scenario = dpos_ros.cli.plot_scenario:main',
            'dpos-process = dpos_ros.cli.process:main',
            'dpos-eval = dpos_ros.cli.evaluate:main',
            'dpos-record = dpos_ros.cli.record:main',
            'dpos-import = dpos_ros.cli.import_:main',
            'dpos-sar = dpos_ros.cli.sar:main',
            'dpos-play = dpos_ros.cli.play:main',
            'dpos-graph = dpos_ros.cli.graph:main',
            'dpos-demo = dpos_ros.cli.demo:main',
            'dpos-campaign = dpos_ros.cli.campaign:main',
        ],
    },
)

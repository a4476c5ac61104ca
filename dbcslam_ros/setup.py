"""ament_python / pip packaging of dbcslam_ros (filter node, CLI, node runtime)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "dbcslam_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    # only the ROS package: research/ (dbcslam_research) is a package of its own
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    package_data={PACKAGE: ["config/*.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    install_requires=[
        "setuptools",
        "numpy",
        "PyYAML",
        "rosbags",
        "mcap",
        "mcap-ros2-support",
        "matplotlib",
        "h5py",
    ],
    zip_safe=True,
    maintainer="DBC-SLAM developers",
    maintainer_email="dbcslam@example.org",
    description="ROS 2 nodes and tools of DBC-SLAM.",
    license="Apache-2.0",
    python_requires=">=3.11",
    entry_points={
        "console_scripts": [
            "dbcslam = dbcslam_ros.cli:console_main",
            "filter_node = dbcslam_ros.node.filter_node:main",
            "talker = dbcslam_ros.node.demo_nodes:talker_main",
            "listener = dbcslam_ros.node.demo_nodes:listener_main",
        ],
    },
)

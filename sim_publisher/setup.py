"""ament_python / pip packaging of sim_publisher (pybullet scenario simulator node)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "sim_publisher"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "tests"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    package_data={PACKAGE: ["data/shapes/*.npy", "data/shapes/README.md"]},
    install_requires=["setuptools", "numpy", "PyYAML", "pybullet"],
    zip_safe=True,
    maintainer="DBC-SLAM developers",
    maintainer_email="dbcslam@example.org",
    description="pybullet simulator node for DBC-SLAM scenarios.",
    license="Apache-2.0",
    python_requires=">=3.11",
    entry_points={
        "console_scripts": ["sim_node = sim_publisher.node:main"],
        # `dbcslam sim`: the dbcslam command line finds its commands in this group, so
        # dbcslam_ros never imports the simulator
        "dbcslam.commands": ["sim = sim_publisher.command:COMMAND"],
    },
)

"""ament_python / pip packaging of dbcslam_core (pure numpy/scipy estimator library)."""

from setuptools import find_packages, setup

PACKAGE = "dbcslam_core"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "tests"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools", "numpy", "scipy", "PyYAML", "numba"],
    zip_safe=False,
    maintainer="DBC-SLAM developers",
    maintainer_email="dbcslam@example.org",
    description="DBC-SLAM estimator core (no ROS).",
    license="Apache-2.0",
    python_requires=">=3.11",
    entry_points={"console_scripts": []},
)

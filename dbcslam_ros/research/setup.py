"""pip packaging of dbcslam_research: the research and benchmark scripts (not a ROS package).

Kept out of what a ROS user installs to run the nodes: colcon builds ``dbcslam_ros`` (whose
setup.py installs only the ``dbcslam_ros`` package) and never descends into this folder. It
declares what the scripts need on top of the ROS package: the simulator (``sim_publisher``,
pybullet) for ``experiments_sim`` and ``bench_live``, matplotlib for the figures.
``make venv`` installs it (editable); ``python -m dbcslam_research.<script>`` runs a script.
"""

from setuptools import find_packages, setup

setup(
    name="dbcslam_research",
    version="0.1.0",
    packages=find_packages(include=["dbcslam_research", "dbcslam_research.*"]),
    install_requires=[
        "dbcslam_core",
        "dbcslam_ros",
        "sim_publisher",
        "numpy",
        "scipy",
        "matplotlib",
        "pybullet",
    ],
    zip_safe=True,
    maintainer="DBC-SLAM developers",
    maintainer_email="dbcslam@example.org",
    description="DBC-SLAM research and benchmark scripts (experiments, benchmarks, MIT push).",
    license="Apache-2.0",
    python_requires=">=3.11",
)

"""dbcslam_research: the scripts that produce the project's results (not installed with the
ROS package).

One ``python -m dbcslam_research.<module>`` entry each; every one writes into ``--out``
(default below ``dbcslam_ros/research/results``, relative to the repository root):

- ``experiments``: the paper's synthetic experiments (edge, gripper) -> targets, figures;
- ``experiments_sim``: the same on pybullet data (``sim_publisher``);
- ``bench``: per-step time and memory of the filter; ``bench_live``: live node CPU and lag;
- ``mitpush_eval``: tracking on the real MIT pushes; ``push_analysis``: what the MIT data
  says about the pusher contact; ``push_nmse``: quasi-static full-push prediction error;
- ``science``: discrepancy-analysis benchmark; ``mitpush_discrepancy``: the discrepancy
  analysis on the MIT pushes (evidence per push model and split);
- ``readme_results``: the README's results section from the results folder.
"""

from __future__ import annotations

__all__: list[str] = []

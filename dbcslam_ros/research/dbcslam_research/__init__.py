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
- ``gripper_evidence``: how much a pybullet grasp says about the jaw friction (per-run
  verdicts of fixed-friction filters); ``friction_calibration``: DBC-SLAM's final friction
  posterior against those verdicts; ``gaussian_particles``: the same evidence from
  particles that carry a Gaussian over pose and twist (a research probe);
- ``tracking_health``: how surprised the filter is by its observations, per run;
- ``step_profile``: wall time per phase of the filter step;
- ``readme_results``: the README's results section from the results folder.
"""

from __future__ import annotations

__all__: list[str] = []

"""dbcslam_core package."""

__all__: list[str] = []

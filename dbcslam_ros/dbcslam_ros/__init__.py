"""dbcslam_ros package."""

__all__: list[str] = []

"""sim_publisher package."""

__all__: list[str] = []

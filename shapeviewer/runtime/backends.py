"""Where the long jobs (``generate``, ``evaluate``) run: local processes, or a Ray cluster for a lab
that outgrows one machine."""

from __future__ import annotations

import os

BACKENDS = ("process", "ray")


def ray_init(workers: int | None = None) -> None:
    """Connect to the Ray cluster at ``RAY_ADDRESS``, or start a local one on ``workers`` CPUs
    (None: all of this machine's); a no-op when Ray is already initialised."""
    import ray

    if os.environ.get("RAY_ADDRESS"):
        ray.init(ignore_reinit_error=True, log_to_driver=False)
    else:
        ray.init(ignore_reinit_error=True, log_to_driver=False, include_dashboard=False, num_cpus=workers)

"""Runtime infrastructure: worker processes, cluster backends, interrupts and progress."""

"""Benchmarks of hub-envs (``make bench``): each module has ``run() -> dict``; :mod:`benchmarks.run` collects them."""

#: Python source ending a child process's script: prints its peak RSS in KiB, ``VmHWM`` of /proc/self/status.
#: Not ``ru_maxrss``: a child that subprocess starts with vfork gets, at exec, its parent's peak RSS as its own
#: ``ru_maxrss`` (measured: 813 MiB for a child whose VmHWM was 13 MiB, under a parent that had touched 800 MiB).
PRINT_PEAK_RSS_KIB = (
    "import resource; "
    "print(next((int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM:')), None) "
    "or resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)"
)

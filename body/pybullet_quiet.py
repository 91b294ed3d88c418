"""pybullet, imported without its banner: naocal's modules `from body.pybullet_quiet import pybullet`.

pybullet prints from C, on the process's stdout and stderr: "pybullet build time: ..." when its module is first
imported, and a b3Warning per link without <inertial> when it loads such a URDF (a user's arm; the warnings would
land in the middle of naocal's --json output). naocal's output (one-line errors, summaries, JSON) is its own:
those calls run inside `c_output_silenced()`, which sends fds 1 and 2 to /dev/null for their duration. (Other
threads' output in that moment would be lost too: naocal uses it before it starts any, and around a load.)
"""

import contextlib
import os
import sys


@contextlib.contextmanager
def c_output_silenced():
    """fds 1 and 2 to /dev/null while the block runs (what C code prints there; Python's streams are flushed)."""
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            stream.flush()
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved + [devnull]:
            os.close(fd)


def _import_quietly():
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    with c_output_silenced():
        import pybullet
    return pybullet


pybullet = _import_quietly()

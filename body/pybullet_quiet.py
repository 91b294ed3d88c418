"""pybullet, imported without its banner: naocal's modules `from body.pybullet_quiet import pybullet`.

pybullet prints "pybullet build time: ..." from C, on the process's stderr, when its module is first imported;
naocal's output (one-line errors, summaries, JSON) is its own. The import runs with fds 1 and 2 sent to /dev/null,
once per process, here only. (Other threads' output in that moment would be lost too: naocal imports this before
it starts any.)
"""

import os
import sys


def _import_quietly():
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            stream.flush()
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        import pybullet
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved + [devnull]:
            os.close(fd)
    return pybullet


pybullet = _import_quietly()

"""Run ``nerfpipe`` commands as a user would, many times, without paying for torch's import each time.

A server process imports nerfpipe once and computes nothing itself (so it holds no thread pools a fork would
copy half-way); each request forks a child that runs the CLI under a memory limit (``RLIMIT_DATA``) and an
alarm, with its output in files. The child's exit status is the command's, or the signal that ended it.

    with ForkServer() as server:
        outcome = server.run(["status", "RUN", "--set", "train.field.levels=3"], cwd=..., limit_bytes=2 << 30,
                             seconds=30)
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

SERVER = r'''
import json, os, resource, signal, sys
import nerfpipe.cli.main, nerfpipe.stages, torch  # imported once, before any fork
# what the stages import when they run, so that no child pays for it again
import av, cv2, kornia, matplotlib.pyplot, open3d, pycolmap, scipy.interpolate, scipy.spatial, trimesh
import nerfpipe.export.mesh, nerfpipe.export.texture, nerfpipe.nerf.policy, nerfpipe.nerf.train.trainer, nerfpipe.report
# first uses that load more (torch's optimizers import its compiler; matplotlib's first 3D figure its toolkit and
# fonts): done once here, computing nothing worth a thread
import io, matplotlib
matplotlib.use("Agg")
torch.optim.Adam([torch.zeros(1, requires_grad=True)])
_figure = matplotlib.pyplot.figure()
_figure.add_subplot(projection="3d").scatter([0.0], [0.0], [0.0])
_figure.savefig(io.BytesIO(), format="png")
matplotlib.pyplot.close(_figure)
print("ready", flush=True)
for line in sys.stdin:
    job = json.loads(line)
    pid = os.fork()
    if pid == 0:
        try:
            os.chdir(job["cwd"])
            out = os.open(job["out"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
            err = os.open(job["err"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
            os.dup2(out, 1)
            os.dup2(err, 2)
            resource.setrlimit(resource.RLIMIT_DATA, (job["limit"], job["limit"]))
            signal.alarm(job["seconds"])
            sys.argv = ["nerfpipe", *job["args"]]
            code = 0
            try:
                nerfpipe.cli.main.main()
            except SystemExit as exit:
                code = exit.code if isinstance(exit.code, int) else (0 if exit.code is None else 1)
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
        except BaseException:
            import traceback
            traceback.print_exc()
            sys.stderr.flush()
            os._exit(99)
    _, status = os.waitpid(pid, 0)
    print(json.dumps({"code": os.waitstatus_to_exitcode(status)}), flush=True)
'''


@dataclass(frozen=True)
class Outcome:
    code: int  # the exit status; negative: killed by that signal (SIGALRM: past its seconds)
    stdout: str
    stderr: str


class ForkServer:
    def __enter__(self) -> "ForkServer":
        # one thread each: servers run side by side, a core each
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        self._process = subprocess.Popen([sys.executable, "-c", SERVER], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, text=True, env=env)
        assert self._process.stdout.readline().strip() == "ready"
        self._tmp = tempfile.TemporaryDirectory()
        return self

    def run(self, args: list[str], cwd: Path, limit_bytes: int, seconds: int) -> Outcome:
        out, err = Path(self._tmp.name) / "out", Path(self._tmp.name) / "err"
        job = {"args": [str(a) for a in args], "cwd": str(cwd), "out": str(out), "err": str(err),
               "limit": limit_bytes, "seconds": seconds}
        self._process.stdin.write(json.dumps(job) + "\n")
        self._process.stdin.flush()
        code = json.loads(self._process.stdout.readline())["code"]
        return Outcome(code, out.read_text(errors="replace"), err.read_text(errors="replace"))

    def __exit__(self, *exc: object) -> None:
        self._process.stdin.close()
        self._process.wait(timeout=30)
        self._tmp.cleanup()

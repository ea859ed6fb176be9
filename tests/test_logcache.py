"""``bench generalize``'s log cache follows what made its logs: the simulator's sources (every
module the family and the session simulator import), the family's base files, the packages."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import sea_daemon
from sea_daemon.apps.bench._logcache import import_closure, producer

# plant 420's logs through bench generalize's cache, the simulation replaced by a small log per
# session; prints how many sessions were simulated
RUN = '''import sys
from pathlib import Path
import numpy as np
from sea_daemon.apps.bench import generalize
from sea_daemon.core.log import MeasuredLog
calls = []
def session(true, duration_s, reference=None, hold_q=None, human=None, seed=0, **_):
    calls.append(seed)
    t = np.arange(50) * 0.01
    x = np.sin(t + seed)[:, None]
    return MeasuredLog(t, x, 0.9 * x, 0.1 * x, None, {}, f"<session {seed}>")
generalize.run_session = session
generalize.plant_logs(420, 2.0, Path(sys.argv[1]))
print(len(calls))
'''


def _copy_package(root: Path) -> Path:
    pkg = root / "sea_daemon"
    shutil.copytree(Path(sea_daemon.__file__).parent, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    return pkg


def _simulated(root: Path, cache: Path) -> int:
    env = dict(os.environ, PYTHONPATH=str(root))
    out = subprocess.run([sys.executable, "-c", RUN, str(cache)], cwd=root, env=env, check=True,
                         capture_output=True, text=True).stdout.split()
    return int(out[-1])


def _edit(path: Path) -> None:
    path.write_text(path.read_text() + "\n# edited\n")


def test_a_simulator_change_makes_the_cached_logs_stale_and_nothing_else_does(tmp_path):
    pkg = _copy_package(tmp_path)
    cache = tmp_path / "cache"
    cache.mkdir(mode=0o700)
    first = _simulated(tmp_path, cache)
    assert first > 0                                          # simulated, then cached
    assert _simulated(tmp_path, cache) == 0                   # read back
    _edit(pkg / "core" / "estimators" / "akf.py")             # not part of the simulation
    assert _simulated(tmp_path, cache) == 0
    _edit(pkg / "core" / "sim" / "plant.py")                  # the plant simulator
    assert _simulated(tmp_path, cache) == first
    assert _simulated(tmp_path, cache) == 0
    _edit(pkg / "data" / "configs" / "exo_1dof.yaml")         # the family's base model
    assert _simulated(tmp_path, cache) == first


MODULES = {
    "pkg/__init__.py": "",
    "pkg/a.py": "import numpy\nfrom pkg.b import f\n\ndef g():\n    from pkg.sub import c  # local import\n    return c\n",
    "pkg/b.py": "import math\nfrom . import d\n\ndef f():\n    return 1\n",
    "pkg/d.py": "X = 1\n",
    "pkg/sub/__init__.py": "",
    "pkg/sub/c.py": "import yaml\n",
    "pkg/unused.py": "import scipy\n",
}


def _tree(root: Path) -> None:
    for name, text in MODULES.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)


def test_the_import_closure_follows_every_import_and_no_other(tmp_path):
    _tree(tmp_path)
    found, others = import_closure(["pkg.a"], root=tmp_path)
    # top-level, inside a function, relative, a package's __init__; not pkg.unused
    assert set(found) == {"pkg", "pkg.a", "pkg.b", "pkg.d", "pkg.sub", "pkg.sub.c"}
    assert found["pkg.sub"] == tmp_path / "pkg" / "sub" / "__init__.py"
    assert others == {"numpy", "yaml"}                        # math is the standard library's


def test_the_producer_changes_with_a_base_file(tmp_path):
    base = tmp_path / "base.yaml"
    base.write_text("a: 1\n")
    modules = ("sea_daemon.core.sim.session",)
    one = producer(modules, [base])
    assert producer(modules, [base]) == one
    assert producer(modules, [tmp_path / "other.yaml"]) != one      # missing counts as missing
    assert producer(modules) != one

"""The compiled kernels' cache follows every kernel module's source, not only the kernel's own
file: a caller compiled with a callee from another module must not keep the old callee's
machine code after that module changes (numba alone checks only the caller's file)."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import sea_daemon

CALLEE = '''from sea_daemon.core.jit import njit


@njit
def shift(x):
    return x + {offset}
'''

CALLER = '''from sea_daemon.core.jit import njit
from sea_daemon.core.probe_callee import shift


@njit
def twice_shifted(x):
    return 2.0 * shift(x)
'''

RUN = '''from sea_daemon.core import jit
jit.KERNEL_MODULES += ("sea_daemon.core.probe_callee", "sea_daemon.core.probe_caller")
from sea_daemon.core.probe_caller import twice_shifted
value = twice_shifted(1.5)
print(value, sum(twice_shifted.stats.cache_hits.values()))
'''


def _copy_package(root: Path) -> Path:
    """The package's sources (no caches) under ``root``, plus the two probe modules."""
    pkg = root / "sea_daemon"
    shutil.copytree(Path(sea_daemon.__file__).parent, pkg,
                    ignore=shutil.ignore_patterns("__pycache__"))
    (pkg / "core" / "probe_callee.py").write_text(CALLEE.format(offset="1.0"))
    (pkg / "core" / "probe_caller.py").write_text(CALLER)
    return pkg


def _run(root: Path) -> tuple[float, int]:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["PYTHONPATH"] = str(root)
    out = subprocess.run([sys.executable, "-c", RUN], cwd=root, env=env, check=True,
                         capture_output=True, text=True).stdout.split()
    return float(out[0]), int(out[1])


def test_caller_follows_an_edited_callee_in_another_module(tmp_path):
    pkg = _copy_package(tmp_path)
    assert _run(tmp_path) == (5.0, 0)          # compiled, cache written
    assert _run(tmp_path) == (5.0, 1)          # loaded from the cache
    (pkg / "core" / "probe_callee.py").write_text(CALLEE.format(offset="2.0"))
    assert _run(tmp_path) == (7.0, 0)          # the caller's file is unchanged: compiled again
    assert _run(tmp_path) == (7.0, 1)          # and cached again


def test_any_kernel_module_edit_makes_the_cache_stale(tmp_path):
    """A kernel module the probe does not even call (e.g. after an upgrade) also counts."""
    pkg = _copy_package(tmp_path)
    assert _run(tmp_path) == (5.0, 0)
    linalg = pkg / "core" / "linalg.py"
    linalg.write_text(linalg.read_text() + "\n# edited\n")
    assert _run(tmp_path) == (5.0, 0)
    assert _run(tmp_path) == (5.0, 1)

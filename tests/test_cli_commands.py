"""The command line's table of commands: every command module is listed, each listed module is a
command, and ``sea-daemon --help`` loads none of them (nor the estimator's libraries)."""
import ast
import importlib
import pkgutil
import subprocess
import sys

import pytest

from sea_daemon.apps import bench as bench_pkg
from sea_daemon.apps import commands
from sea_daemon.apps.commands.bench import BENCHMARKS

#: modules of the commands package that are helpers of the commands, not commands (demo --robot
#: is demo_robot, the flow both demos share demo_flow)
HELPERS = {"daemon_args", "demo_flow", "demo_robot"}


@pytest.mark.parametrize("package, table, helpers", [
    (commands, commands.COMMANDS, HELPERS),
    (bench_pkg, BENCHMARKS, set()),
], ids=["commands", "benchmarks"])
def test_the_table_lists_every_command_module_once_and_each_is_a_command(package, table, helpers):
    modules = {m.name for m in pkgutil.iter_modules(package.__path__) if not m.name.startswith("_")} - helpers
    assert sorted(c.module for c in table) == sorted(modules)
    assert len({c.name for c in table}) == len(table)
    for c in table:
        mod = importlib.import_module(f"{package.__name__}.{c.module}")
        assert callable(mod.add_arguments) and callable(mod.run), c
        assert c.help and "\n" not in c.help, c


def _loaded_by(argv: list[str]) -> tuple[str, list]:
    """``sea-daemon ARGV`` in a fresh interpreter: (what it printed, the command modules and
    numpy it imported)."""
    code = ("import sys\n"
            "from sea_daemon.apps.cli import main\n"
            "try:\n"
            f"    main({argv!r})\n"
            "except SystemExit:\n"
            "    pass\n"
            "print('LOADED', sorted(m for m in sys.modules if m.startswith('sea_daemon.apps.commands.') "
            "or m == 'numpy'))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60).stdout
    text, _, loaded = out.rpartition("LOADED ")
    return text, ast.literal_eval(loaded.strip())


def test_help_imports_no_command_module_and_no_numpy():
    out, loaded = _loaded_by(["--help"])
    assert loaded == [], out
    for c in commands.COMMANDS:
        assert c.name in out


def test_a_chosen_command_loads_only_its_own_module():
    out, loaded = _loaded_by(["reset", "--help"])
    assert [m for m in loaded if m != "numpy"] == ["sea_daemon.apps.commands.reset"], out

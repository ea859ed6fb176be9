"""Configuration files: read and write the model YAML, the project's paths.

The configuration itself is the validated, frozen dataclasses of
:mod:`sea_daemon.core.config`; this module is where they meet the file system.
"""
from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import yaml

from sea_daemon import data
from sea_daemon.core.config import ModelConfig
from sea_daemon.errors import ConfigError, shown
from sea_daemon.io.files import atomic_write_text, read_text


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader with bounds: nesting depth, alias count and the size of the document
    once aliases are expanded; duplicate keys refused; numbers by a strict grammar (no ``1_0``,
    no sexagesimal ``1:20``, no hex)."""

    def __init__(self, stream, source: str):
        super().__init__(stream)
        self.source = source
        self.depth = 0
        self.aliases = 0

    def _fail(self, mark, problem: str):
        where = f"line {mark.line + 1}" if mark is not None else "<file>"
        raise ConfigError(self.source, where, problem)

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            self.aliases += 1
            if self.aliases > MAX_ALIASES:
                self._fail(self.peek_event().start_mark, f"more than {MAX_ALIASES} aliases (*name), allowed <= {MAX_ALIASES}")
        self.depth += 1
        if self.depth > MAX_DEPTH:
            self._fail(self.peek_event().start_mark, f"nested deeper than {MAX_DEPTH} levels, allowed <= {MAX_DEPTH}")
        try:
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1

    def get_single_node(self):
        node = super().get_single_node()
        if node is not None:
            size: dict[int, int] = {}

            def expanded(n) -> int:          # nodes once every alias is expanded (memoised per node)
                k = id(n)
                if k not in size:
                    size[k] = 1               # a cycle counts once: PyYAML builds it as a reference
                    if isinstance(n, yaml.MappingNode):
                        size[k] += sum(expanded(a) + expanded(b) for a, b in n.value)
                    elif isinstance(n, yaml.SequenceNode):
                        size[k] += sum(expanded(a) for a in n.value)
                    if size[k] > MAX_NODES:
                        self._fail(n.start_mark, f"expands to more than {MAX_NODES} values (aliases), "
                                                 f"allowed <= {MAX_NODES}")
                return size[k]
            expanded(node)
        return node

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                key = key_node.value if isinstance(key_node, yaml.ScalarNode) else None
                if key is not None and key != "<<":
                    if key in seen:
                        self._fail(key_node.start_mark, f"duplicate key {shown(key, 40)!r}")
                    seen.add(key)
        return super().construct_mapping(node, deep=deep)


#: bounds of a configuration document
MAX_DEPTH, MAX_ALIASES, MAX_NODES = 32, 64, 100_000

# numbers: decimal integers and floats only (YAML 1.1's underscores, sexagesimal, hex and octal
# forms are strings here, so they fail validation with a clear message instead of a surprise)
_BoundedLoader.yaml_implicit_resolvers = {
    k: [(tag, rx) for tag, rx in v if tag not in ("tag:yaml.org,2002:int", "tag:yaml.org,2002:float")]
    for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_BoundedLoader.add_implicit_resolver(
    "tag:yaml.org,2002:int", re.compile(r"^[-+]?(?:0|[1-9][0-9]*)$"), list("-+0123456789"))
_BoundedLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^(?:[-+]?(?:[0-9]+\.[0-9]*|\.[0-9]+|[0-9]+)(?:[eE][-+]?[0-9]+)?|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"),
    list("-+0123456789."))


def load_yaml(path: str | Path) -> Any:
    """Read a YAML file with the bounds of :class:`_BoundedLoader`: at most
    :data:`~sea_daemon.io.files.MAX_CONFIG_BYTES`, UTF-8, no duplicate keys; every problem is a
    :class:`ConfigError` naming the file and the line."""
    p = str(path)
    text = read_text(p, what="YAML file")
    loader = _BoundedLoader(text, p)
    try:
        return loader.get_single_data()
    except ConfigError:
        raise
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "<file>"
        raise ConfigError(shown(p), where, f"not valid YAML: {shown(getattr(e, 'problem', e))}") from None
    except (ValueError, OverflowError, RecursionError) as e:     # a number beyond Python's limits
        raise ConfigError(shown(p), "<file>", f"value out of range: {shown(e)}") from None
    finally:
        loader.dispose()


def load_config(path: str | Path) -> ModelConfig:
    """Load and validate a model configuration (docs/interfaces.md §2); a ``model.urdf`` it names
    is read relative to the YAML's folder (at most :data:`~sea_daemon.io.files.MAX_CONFIG_BYTES`)."""
    d = load_yaml(path)
    return ModelConfig.from_dict(d, source=str(path), urdf_text=read_urdf(d, path))


def read_urdf(d: Any, path: str | Path) -> str | None:
    """The text of the URDF that ``model.urdf`` of the YAML mapping ``d`` names (relative to the
    folder of ``path``), or None where it names none (the validation of the key is the config's)."""
    model = d.get("model") if isinstance(d, dict) else None
    rel = model.get("urdf") if isinstance(model, dict) else None
    if not isinstance(rel, str) or not rel.strip():
        return None
    return read_text(urdf_path(path, rel), what="URDF file (model.urdf)")


def urdf_path(yaml_path: str | Path, rel: str) -> Path:
    """The file a ``model.urdf`` value names: relative to the YAML's folder (absolute as given)."""
    return Path(yaml_path).parent / rel


def config_text(cfg: ModelConfig, source: str | Path) -> str:
    """``cfg`` as the YAML text :func:`save_config` writes, after reading that text back the way
    :func:`load_config` does: a configuration the loader would refuse (an effect parameter out
    of its range, a value beyond ±1e9, ...) is the loader's :class:`ConfigError`, naming
    ``source`` and the key, and nothing is written.  A ``model.urdf`` is written relative to
    ``source``'s folder (the same file as the configuration's own names)."""
    d = cfg.to_dict()
    urdf = None
    if cfg.model.rigid is not None:
        urdf = cfg.model.rigid.urdf
        here = urdf_path(cfg.source, cfg.model.urdf)
        if Path(cfg.source).parent.resolve() != Path(source).parent.resolve() and not Path(cfg.model.urdf).is_absolute():
            d["model"]["urdf"] = os.path.relpath(here.resolve(), Path(source).parent.resolve())
    text = yaml.safe_dump(d, sort_keys=False, default_flow_style=None)
    loader = _BoundedLoader(text, str(source))
    try:
        ModelConfig.from_dict(loader.get_single_data(), source=str(source), urdf_text=urdf)
    finally:
        loader.dispose()
    return text


def save_config(cfg: ModelConfig, path: str | Path, header: str | None = None) -> None:
    """Write, atomically, a configuration that :func:`load_config` reads back to an equal object
    (:func:`config_text`: one the loader refuses is refused here, the target left as it was)."""
    text = config_text(cfg, path)
    if header:       # paths in the header shown printably (bytes that are not UTF-8 escaped)
        text = "".join(f"# {shown(line, 1000)}\n" for line in header.splitlines()) + text
    atomic_write_text(path, text)


def data_root() -> Path:
    """The package data (:mod:`sea_daemon.data`): ``configs/`` (model YAML, scenarios, EDS files)
    and ``systemd/``."""
    return data.path()


def import_root() -> Path:
    """The folder a child Python process needs on ``PYTHONPATH`` to import this ``sea_daemon``
    (a checkout or site-packages)."""
    return Path(data.__file__).resolve().parent.parent.parent


def default_config_path() -> Path:
    return data_root() / "configs" / "exo_1dof.yaml"

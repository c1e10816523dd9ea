"""Parameter layering of `pf-slam run`: parameter files, their names and values checked before
anything starts, the layers merged per node."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from .common import INPUT_TYPES, NODE_NAMES, RunError


def flatten(d: dict, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, name + "."))
        else:
            out[name] = v
    return out


def unflatten(flat: dict[str, Any]) -> dict:
    out: dict = {}
    for name, v in flat.items():
        *parents, leaf = name.split(".")
        d = out
        for p in parents:
            d = d.setdefault(p, {})
        d[leaf] = v
    return out


def load_params(path: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """A ROS 2 parameter YAML -> {node name or '/**': flat {dotted name: value}}."""
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text())
    except OSError as e:
        raise RunError(f"{p}: cannot read parameter file: {e}") from None
    except yaml.YAMLError as e:  # one line: where and what (PyYAML's own text spans lines)
        mark = getattr(e, "problem_mark", None)
        at = f":{mark.line + 1}:{mark.column + 1}" if mark is not None else ""
        what = " ".join(x for x in (getattr(e, "context", None), getattr(e, "problem", None)) if x) or str(e)
        raise RunError(f"{p}{at}: cannot read parameter file: not valid YAML: {' '.join(what.split())}") from None
    if not isinstance(doc, dict):
        raise RunError(f"{p}: not a ROS 2 parameter file (expected a mapping of node names)")
    out: dict[str, dict[str, Any]] = {}
    for node, body in doc.items():
        if not isinstance(body, dict) or "ros__parameters" not in body:
            raise RunError(f"{p}: section {node!r} has no 'ros__parameters'")
        key = node if node == "/**" else str(node).lstrip("/")
        if key != "/**" and key not in NODE_NAMES + ("texture",):
            raise RunError(f"{p}: unknown node {node!r}; nodes: {', '.join(NODE_NAMES)}")
        params = body["ros__parameters"] or {}
        if not isinstance(params, dict):
            raise RunError(f"{p}: section {node!r}: 'ros__parameters' must be a mapping of names to values")
        flat = flatten(params)
        check_names(p, node, key, flat)
        out.setdefault(key, {}).update(flat)
    return out


def check_names(path: Path, section: str, key: str, flat: dict[str, Any]) -> None:
    """RunError for the first name of a parameter file's section that no node would read:
    in a node's section, one that node does not declare; in '/**', one no node declares
    (`topics.*` are `pf-slam run`'s own). Names the file, the section, the name and the
    nearest declared one. (ROS itself ignores undeclared overrides: a typo would silently
    leave the default.)"""
    from ..nodes.declared import RUN_KEYS_PREFIXES, declared, declared_by, nearest

    by = declared_by()
    for name in flat:
        if key == "/**":
            run_keys = [f"{prefix}{r}" for prefix in RUN_KEYS_PREFIXES for r in INPUT_TYPES]
            if name in by or name in run_keys:
                continue
            known = run_keys if name.startswith(RUN_KEYS_PREFIXES) else list(by) + run_keys
            where = (
                ("the inputs are " + ", ".join(INPUT_TYPES))
                if name.startswith(RUN_KEYS_PREFIXES)
                else "no node declares it"
            )
        else:
            if name in declared(key):
                continue
            known = list(declared(key))
            where = (
                (
                    f"{key} does not declare it (declared by {', '.join(by[name])}: put it in that "
                    "section or under '/**')"
                )
                if name in by
                else f"{key} does not declare it"
            )
        near = nearest(name, known)
        hint = f"; nearest known: '{near}'" if near else ""
        raise RunError(f"{path}: section {section!r}: unknown parameter '{name}' ({where}){hint}")


#: `pf-slam run` flags -> the parameter they set (named in errors)
CLI_FLAGS = {"filter.num_particles": "--particles", "filter.seed": "--seed", "rate": "--rate"}


def filter_overrides(args: Any) -> dict[str, dict[str, Any]]:
    """--particles N / --seed S (pf-slam run and live) -> {"/**": {filter.num_particles, filter.seed}}."""
    o: dict[str, Any] = {}
    if getattr(args, "particles", None) is not None:
        o["filter.num_particles"] = args.particles
    if getattr(args, "seed", None) is not None:
        o["filter.seed"] = args.seed
    return {"/**": o} if o else {}


def check_node_values(per_node: dict[str, dict[str, Any]], labelled: list[tuple[Callable[[str], str], dict]]) -> None:
    """RunError (one line) for the first value a node would refuse at start-up (bad type, a
    config out of range: what the nodes check when built), naming where it was set, before
    anything is created. `labelled`: the layers (as node_params) with a function section ->
    where that layer's values come from."""
    from ..nodes.bag_replay import parse_rate
    from ..nodes.declared import check_values

    for node, params in per_node.items():
        bad = check_values(node, params)
        if bad is None and node == "bag_replay":
            try:
                parse_rate(str(params.get("rate", "max")))
            except ValueError as e:
                bad = ("rate", str(e))
        if bad is None:
            continue
        name, what = bad
        where = "defaults"
        for label, layer in reversed(labelled):
            sec = node if name in layer.get(node, {}) else ("/**" if name in layer.get("/**", {}) else None)
            if sec is not None:
                where = label(sec)
                break
        if where == "the command line" and name in CLI_FLAGS:
            where = f"the command line ({CLI_FLAGS[name]})"
        raise RunError(f"{where}: parameter '{name}' of {node}: {what}")


def node_params(layers: list[dict[str, dict[str, Any]]], node: str) -> dict[str, Any]:
    """Merge layers (later wins): per layer, '/**' then the node's own section."""
    merged: dict[str, Any] = {}
    for layer in layers:
        merged.update(layer.get("/**", {}))
        merged.update(layer.get(node, {}))
    return merged


def params_topics(layer: dict[str, dict[str, Any]]) -> dict[str, str]:
    """`topics.<input>` values of a parameter file's '/**' section (removed from it: no node
    declares them), e.g. ``topics: {scan: /front/scan, odom: /wheel/odom}``."""
    shared = layer.get("/**", {})
    return {k.split(".", 1)[1]: str(shared.pop(k)) for k in [k for k in shared if k.startswith("topics.")]}


def _default_particles() -> int:
    from ..core.config import FilterConfig

    return FilterConfig().num_particles

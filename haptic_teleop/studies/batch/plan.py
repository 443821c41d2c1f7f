"""What a sweep runs: its axes (swept keys), its points (a value per axis and a seed), the sweep
file's schema, grid and random plans, and each point's resolved scene and run hash.

A plan is built and every point's scene loaded (validated) before anything runs: a bad key or
value exits 2 with one line and writes nothing. docs/sweep.md describes the file.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from haptic_teleop.errors import ConfigError

KEY_JOIN = "+"
SEED_MAX = 2**63 - 1
FILE_KEYS = ("scene", "description", "set", "grid", "random", "seeds", "metrics", "keep_bags")
RANDOM_KEYS = ("count", "seed", "params")
DISTRIBUTIONS = {
    "uniform": "[low, high]: a float drawn uniformly",
    "loguniform": "[low, high] with 0 < low: a float whose log is uniform",
    "integers": "[low, high]: an integer from low to high, both included",
    "choice": "[v1, v2, ...]: one of the values, each equally likely",
}


@dataclass(frozen=True)
class Param:
    """One swept axis: the key paths it sets (all to the same value) and its values, as override text."""

    keys: tuple[str, ...]
    values: tuple[str, ...]

    @property
    def label(self) -> str:
        return KEY_JOIN.join(self.keys)


@dataclass(frozen=True)
class Spec:
    """A sweep before its scenes are loaded: from a sweep file or from today's flags."""

    scene: str
    source: str  # where the axes came from (the sweep file, or "--param") for error lines
    sets: tuple[str, ...] = ()  # fixed overrides, KEY=VALUE text
    params: tuple[Param, ...] = ()  # the axes; each one's values in first-seen order
    combos: tuple[tuple[str, ...], ...] = ()  # one value per axis, in plan order
    seeds: tuple[int, ...] | None = None
    metrics: tuple[str, ...] | None = None
    keep_bags: bool = False
    random: bool = False  # the combos are a random sample (not every combination)
    # override text -> where it came from (a sweep file's section), to blame errors on the file
    origins: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Point:
    """One run of a sweep: its axis values, seed, resolved scene and run hash."""

    index: int
    combo: tuple[str, ...]
    seed: int
    scene: Any  # LoadedScene
    run_hash: str
    keys: Mapping[str, Any]  # swept key path -> its value in the resolved scene (table cell)


# --- text of values --------------------------------------------------------------------------------


def split_values(text: str) -> list[str]:
    """`a,b,[1, 2],{x: 1}` -> ["a", "b", "[1, 2]", "{x: 1}"]: commas inside brackets stay."""
    out: list[str] = []
    depth = 0
    cur: list[str] = []
    for ch in text:
        if ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        if ch == "," and depth == 0:
            out.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
    out.append("".join(cur).strip())
    return out


def value_text(value: Any) -> str:
    """A YAML value as the text of a `--set KEY=TEXT` that parses back to it (1e-05 -> 1.0e-05)."""
    import yaml

    if isinstance(value, str):
        return value if _reparses(value) else json.dumps(value)
    text = str(yaml.safe_dump(value, default_flow_style=True, width=1 << 20)).strip()
    return text.removesuffix("...").strip()


def _reparses(text: str) -> bool:
    import yaml

    try:
        return bool(yaml.safe_load(text) == text)
    except yaml.YAMLError:
        return False


def _key_ok(key: str) -> bool:
    return bool(key) and all(part.strip() for part in key.split("."))


# --- today's flags -------------------------------------------------------------------------------


def parse_param(text: str) -> Param:
    """`KEY.PATH[+KEY.PATH...]=v1,v2,...` -> Param; ConfigError (exit 2) when it is malformed."""
    allowed = "allowed: KEY.PATH=v1,v2,... (join keys with + to set them together), e.g. scene.seed=1,2"
    key, eq, values = text.partition("=")
    if not eq:
        raise ConfigError("--param", text, text, allowed)
    keys = tuple(k.strip() for k in key.split(KEY_JOIN))
    for k in keys:
        if not _key_ok(k):
            raise ConfigError("--param", key, text, allowed)
    vals = tuple(split_values(values))
    if any(v == "" for v in vals):
        raise ConfigError("--param", key, values, "allowed: a comma-separated list of non-empty values")
    if len(set(vals)) != len(vals):
        raise ConfigError("--param", key, values, "allowed: each value once")
    return Param(keys, vals)


def parse_seeds(text: str | None) -> list[int] | None:
    if text is None:
        return None
    allowed = "allowed: comma-separated integers from 0 to 2**63 - 1"
    seeds: list[int] = []
    for part in split_values(text):
        try:
            seed = int(part)
        except ValueError:
            raise ConfigError("--seeds", "scene.seed", part, allowed) from None
        if not 0 <= seed <= SEED_MAX:
            raise ConfigError("--seeds", "scene.seed", part, allowed)
        seeds.append(seed)
    if len(set(seeds)) != len(seeds):
        raise ConfigError("--seeds", "scene.seed", text, "allowed: each seed once")
    return seeds


def combinations(params: Sequence[Param]) -> list[tuple[str, ...]]:
    """Every combination of the parameters' values, the first parameter varying slowest."""
    return list(itertools.product(*(p.values for p in params)))


def overrides_for(params: Sequence[Param], combo: Sequence[str]) -> list[str]:
    return [f"{k}={v}" for p, v in zip(params, combo, strict=True) for k in p.keys]


def spec_from_flags(scene: str, param_texts: Sequence[str]) -> Spec:
    from haptic_teleop.scene.load import find_scene

    params = tuple(parse_param(t) for t in param_texts)
    _check_axes_once(params, "--param")
    return Spec(scene=str(find_scene(scene)), source="--param", params=params, combos=tuple(combinations(params)))


def _check_axes_once(params: Sequence[Param], source: str) -> None:
    seen: set[str] = set()
    for p in params:
        for k in p.keys:
            if k in seen:
                raise ConfigError(source, k, p.label, "allowed: each key swept once")
            seen.add(k)


# --- sweep files ---------------------------------------------------------------------------------


def is_sweep_file(path: Path) -> bool:
    """A YAML mapping with a `grid` or `random` section, or whose `scene` is a name (a scene file
    has neither, and its `scene` is a section)."""
    from haptic_teleop.scene.yaml_text import parse_yaml

    if path.suffix not in (".yaml", ".yml") or not path.is_file():
        return False
    try:
        raw = parse_yaml(path.read_text(encoding="utf-8"), str(path))
    except (ConfigError, OSError, UnicodeDecodeError):
        return False
    return isinstance(raw, dict) and ("grid" in raw or "random" in raw or isinstance(raw.get("scene"), str))


def find_sweep(name: str) -> Path | None:
    """A sweep file by path, or a bundled one by name (`delay_loss_wall_contact`); None if neither."""
    from haptic_teleop.resources import sweeps_dir

    p = Path(name)
    if is_sweep_file(p):
        return p
    cand = sweeps_dir() / (p.name if p.suffix else p.name + ".yaml")
    if not p.exists() and is_sweep_file(cand):
        return cand
    return None


def load_sweep_file(path: Path) -> Spec:
    """Read and check a sweep file (docs/sweep.md); ConfigError naming the key and what is allowed."""
    from haptic_teleop.scene.yaml_text import parse_yaml, read_scene_text

    src = str(path)
    raw = parse_yaml(read_scene_text(path, src), src)
    if not isinstance(raw, dict):
        raise ConfigError(src, "", raw, f"allowed: a mapping with keys {', '.join(FILE_KEYS)}")
    for k in raw:
        if k not in FILE_KEYS:
            raise ConfigError(src, str(k), raw[k], f"unknown key; allowed: {', '.join(FILE_KEYS)}")
    scene = raw.get("scene")
    if not isinstance(scene, str) or not scene.strip():
        raise ConfigError(src, "scene", scene, "required; allowed: a bundled scene name or a scene file path")
    scene_path = _scene_path(scene.strip(), path)
    origins: dict[str, str] = {}
    sets = tuple(_fixed_sets(raw.get("set"), src, origins))
    if raw.get("grid") is None and raw.get("random") is None:
        raise ConfigError(src, "grid", None, "a sweep file needs a grid or a random section (or both)")
    grid_params = _grid(raw.get("grid"), src, origins) if "grid" in raw else []
    rand_params, samples = _random(raw.get("random"), src, origins) if "random" in raw else ([], [])
    params = (*grid_params, *rand_params)
    _check_axes_once(params, src)
    grid_combos = combinations(grid_params)
    combos = [g + r for g in grid_combos for r in samples] if rand_params else grid_combos
    seeds = raw.get("seeds")
    if seeds is not None:
        seeds = _seeds(seeds, src)
    metrics = raw.get("metrics")
    if metrics is not None and (
        not isinstance(metrics, list) or not metrics or not all(isinstance(m, str) and m for m in metrics)
    ):
        raise ConfigError(src, "metrics", metrics, "allowed: a non-empty list of summary.json keys")
    keep = raw.get("keep_bags", False)
    if not isinstance(keep, bool):
        raise ConfigError(src, "keep_bags", keep, "allowed: true or false")
    return Spec(
        scene=scene_path,
        source=src,
        sets=sets,
        params=params,
        combos=tuple(combos),
        seeds=tuple(seeds) if seeds is not None else None,
        metrics=tuple(metrics) if metrics is not None else None,
        keep_bags=keep,
        random=bool(rand_params),
        origins=origins,
    )


def _scene_path(scene: str, sweep_file: Path) -> str:
    """Relative to the sweep file's folder first, then as given, then a bundled scene's name."""
    from haptic_teleop.scene.load import find_scene

    beside = sweep_file.parent / scene
    if beside.is_file():
        return str(beside)
    return str(find_scene(scene))


def _fixed_sets(section: Any, src: str, origins: dict[str, str]) -> list[str]:
    if section is None:
        return []
    if not isinstance(section, dict):
        raise ConfigError(src, "set", section, "allowed: a mapping KEY.PATH: value (fixed for every run)")
    out = []
    for key, value in section.items():
        if not isinstance(key, str) or not _key_ok(key) or KEY_JOIN in key:
            raise ConfigError(src, f"set.{key}", value, "allowed: a dotted key path like scene.duration_s")
        text = f"{key}={value_text(value)}"
        origins[text] = f"{src}: set"
        out.append(text)
    return out


def _axis_keys(key: Any, src: str, where: str, value: Any) -> tuple[str, ...]:
    keys = tuple(k.strip() for k in key.split(KEY_JOIN)) if isinstance(key, str) else ()
    if not keys or not all(_key_ok(k) for k in keys):
        raise ConfigError(
            src, f"{where}.{key}", value, "allowed: a dotted key path, or several joined with + (set together)"
        )
    return keys


def _grid(section: Any, src: str, origins: dict[str, str]) -> list[Param]:
    allowed = "allowed: a mapping KEY.PATH (or KEY1+KEY2): [v1, v2, ...]"
    if not isinstance(section, dict) or not section:
        raise ConfigError(src, "grid", section, allowed)
    params = []
    for key, values in section.items():
        keys = _axis_keys(key, src, "grid", values)
        if not isinstance(values, list) or not values:
            raise ConfigError(src, f"grid.{key}", values, "allowed: a non-empty list of values")
        texts = tuple(value_text(v) for v in values)
        if len(set(texts)) != len(texts):
            raise ConfigError(src, f"grid.{key}", values, "allowed: each value once")
        for k in keys:
            for t in texts:
                origins[f"{k}={t}"] = f"{src}: grid.{key}"
        params.append(Param(keys, texts))
    return params


def _random(section: Any, src: str, origins: dict[str, str]) -> tuple[list[Param], list[tuple[str, ...]]]:
    """The random section -> its axes and `count` samples (one value per axis), drawn with a
    numpy Generator seeded by `seed`: the same file gives the same points everywhere."""
    import numpy as np

    if not isinstance(section, dict):
        raise ConfigError(src, "random", section, "allowed: a mapping with count, seed (0) and params")
    for k in section:
        if k not in RANDOM_KEYS:
            raise ConfigError(src, f"random.{k}", section[k], f"unknown key; allowed: {', '.join(RANDOM_KEYS)}")
    count: Any = section.get("count")
    if not _is_int(count) or count < 1:
        raise ConfigError(src, "random.count", count, "required; allowed: a whole number >= 1 (points drawn)")
    seed = section.get("seed", 0)
    if not _is_int(seed) or not 0 <= seed <= SEED_MAX:
        raise ConfigError(src, "random.seed", seed, "allowed: an integer from 0 to 2**63 - 1 (the sampler's seed)")
    dists = section.get("params")
    if not isinstance(dists, dict) or not dists:
        raise ConfigError(
            src, "random.params", dists, "required; allowed: a mapping KEY.PATH: {uniform: [low, high]} (or ...)"
        )
    draws = []
    for key, dist in dists.items():
        keys = _axis_keys(key, src, "random.params", dist)
        draws.append((keys, *_distribution(dist, src, f"random.params.{key}")))
    rng = np.random.default_rng(seed)
    samples: list[tuple[str, ...]] = []
    for _ in range(count):
        samples.append(tuple(value_text(_draw(rng, kind, args)) for _, kind, args in draws))
    params = []
    for i, (keys, _, _) in enumerate(draws):
        texts = tuple(dict.fromkeys(s[i] for s in samples))
        for k in keys:
            for t in texts:
                origins[f"{k}={t}"] = f"{src}: random.params.{KEY_JOIN.join(keys)}"
        params.append(Param(keys, texts))
    return params, samples


def _distribution(dist: Any, src: str, where: str) -> tuple[str, list[Any]]:
    allowed = "allowed: one of " + "; ".join(f"{{{k}: {v}}}" for k, v in DISTRIBUTIONS.items())
    if not isinstance(dist, dict) or len(dist) != 1:
        raise ConfigError(src, where, dist, allowed)
    ((kind, args),) = dist.items()
    if kind not in DISTRIBUTIONS or not isinstance(args, list) or not args:
        raise ConfigError(src, where, dist, allowed)
    if kind == "choice":
        return kind, args
    if len(args) != 2 or not all(_is_number(a) for a in args) or not args[0] <= args[1]:
        raise ConfigError(src, where, dist, f"allowed: {{{kind}: {DISTRIBUTIONS[kind]}}} with low <= high")
    if kind == "integers" and not all(_is_int(a) for a in args):
        raise ConfigError(src, where, dist, f"allowed: {{integers: {DISTRIBUTIONS['integers']}}}, whole numbers")
    if kind == "loguniform" and not args[0] > 0:
        raise ConfigError(src, where, dist, f"allowed: {{loguniform: {DISTRIBUTIONS['loguniform']}}}")
    return kind, args


def _draw(rng: Any, kind: str, args: list[Any]) -> Any:
    if kind == "uniform":
        return float(rng.uniform(args[0], args[1]))
    if kind == "loguniform":
        return float(math.exp(rng.uniform(math.log(args[0]), math.log(args[1]))))
    if kind == "integers":
        return int(rng.integers(args[0], args[1], endpoint=True))
    return args[int(rng.integers(len(args)))]


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _seeds(seeds: Any, src: str) -> list[int]:
    allowed = "allowed: a non-empty list of distinct integers from 0 to 2**63 - 1"
    if not isinstance(seeds, list) or not seeds:
        raise ConfigError(src, "seeds", seeds, allowed)
    for s in seeds:
        if not _is_int(s) or not 0 <= s <= SEED_MAX:
            raise ConfigError(src, "seeds", s, allowed)
    if len(set(seeds)) != len(seeds):
        raise ConfigError(src, "seeds", seeds, allowed)
    return list(seeds)


# --- points: resolved scenes and their hashes ------------------------------------------------------


def canonical_config(config: Any) -> str:
    """The resolved scene as canonical JSON (sorted keys, no spaces): what the run hash is of."""
    return json.dumps(asdict(config), sort_keys=True, separators=(",", ":"), default=str, allow_nan=True)


def run_hash(config: Any, seed: int) -> str:
    """The key of a run: SHA-256 of the resolved scene's canonical JSON and the seed (16 hex digits)."""
    payload = json.dumps({"scene": canonical_config(config), "seed": seed}, sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def key_value(config: Any, key: str) -> Any:
    """The value at a dotted key path of the resolved scene, as a table cell: a number, a string,
    a bool, None, or JSON text for a list or a section."""
    node: Any = asdict(config)
    for part in key.split("."):
        if isinstance(node, (list, tuple)) and part.isdigit() and int(part) < len(node):
            node = node[int(part)]
        elif isinstance(node, dict) and part in node:
            node = node[part]
        else:
            return None
    if isinstance(node, (list, tuple, dict)):
        return json.dumps(node, sort_keys=True)
    return node


def resolve(spec: Spec, seeds: Sequence[int] | None = None) -> list[Point]:
    """Load (validate) every point's scene, in plan order: combinations, each with every seed.
    Without seeds (`--seeds`, the file's `seeds`) each point keeps its scene's `scene.seed`, which
    may be a swept key; with them, sweeping scene.seed too is refused (the two would collide)."""
    from haptic_teleop.scene.load import load_scene

    use_seeds: list[int | None] = list(seeds if seeds is not None else spec.seeds or [None])
    keys = [k for p in spec.params for k in p.keys]
    if use_seeds != [None] and "scene.seed" in keys:
        source = "--seeds" if seeds is not None else spec.source
        raise ConfigError(
            source, "scene.seed", use_seeds, "scene.seed is swept too; allowed: sweep the seed one way, not both"
        )
    _load(load_scene, spec, list(spec.sets), None)  # the fixed part alone: its errors first
    points: list[Point] = []
    for combo in spec.combos:
        ov = [*spec.sets, *overrides_for(spec.params, combo)]
        for seed in use_seeds:
            scene = _load(load_scene, spec, ov, seed)
            used = int(scene.config.scene.seed)
            points.append(
                Point(
                    index=len(points),
                    combo=combo,
                    seed=used,
                    scene=scene,
                    run_hash=run_hash(scene.config, used),
                    keys={k: key_value(scene.config, k) for k in keys},
                )
            )
    return points


def _load(load_scene: Any, spec: Spec, overrides: list[str], seed: int | None) -> Any:
    try:
        return load_scene(spec.scene, overrides=overrides, seed=seed)
    except ConfigError as exc:
        origin = spec.origins.get(exc.source.removeprefix("--set "))
        if origin is None:
            raise
        raise ConfigError(origin, exc.key_path, exc.value, exc.allowed) from None

"""A dataset directory as a whole: ``manifest.json`` plus its shards. Info, verification, conversion."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Callable, Iterator, Optional

import numpy as np

from madp.errors import SettingError
from madp.io.lock import LOCK_FILENAME, locked_dir
from madp.io.owned import clear_owned, foreign_files

from .manifest import MANIFEST_FILENAME, Manifest, ShardInfo, SplitInfo
from .schema import DataError, SampleBatch
from .shard_io import check_shard, convert_shard, iter_shard


def open_dataset(root: os.PathLike | str) -> Manifest:
    """Load and validate ``root/manifest.json`` (one-line DataError naming the file otherwise)."""
    root = Path(root)
    if not root.is_dir():
        raise DataError.at(root, "is not a dataset directory")
    return Manifest.load(root / MANIFEST_FILENAME)


def iter_split(root: os.PathLike | str, manifest: Manifest, split: str, batch_size: int = 256) -> Iterator[SampleBatch]:
    for p in manifest.shard_paths(split, root):
        yield from iter_shard(p, manifest.format, batch_size=batch_size)


def check_shards(root: os.PathLike | str, manifest: Manifest, splits: Optional[tuple[str, ...]] = None) -> None:
    """Check every shard of ``splits`` (default all) against the manifest before use: size, sha256
    (one streamed read each) and the counts and N its footer declares. DataError naming the file."""
    for name in splits or tuple(manifest.splits):
        if name not in manifest.splits:
            continue
        for s in manifest.splits[name].shards:
            check_shard(Path(root) / s.file, s, manifest.format, num_robots=manifest.num_robots)


def manifest_files(root: os.PathLike | str) -> list[str]:
    """What a manifest says madp wrote in ``root``: the manifest and its shards (relative paths)."""
    out = [MANIFEST_FILENAME]
    try:
        m = Manifest.load(Path(root) / MANIFEST_FILENAME)
    except DataError:
        return out
    return out + [s.file for sp in m.splits.values() for s in sp.shards]


def dataset_info(root: os.PathLike | str) -> dict:
    """Counts, sizes, parameters and statistics of a dataset, as a JSON-able dict."""
    m = open_dataset(root)
    splits = {}
    for name, sp in m.splits.items():
        size = sum(s.bytes for s in sp.shards)
        splits[name] = {"samples": sp.num_samples, "episodes": sp.num_episodes, "shards": len(sp.shards),
                        "bytes": size}
    total = sum(s["bytes"] for s in splits.values())
    return {
        "root": str(root),
        "format": m.format,
        "schema_version": m.schema_version,
        "code_version": m.code_version,
        "num_robots": m.num_robots,
        "num_samples": m.num_samples,
        "bytes": total,
        "bytes_per_sample": total / max(m.num_samples, 1),
        "splits": splits,
        "action_stats": m.action_stats.to_dict() if m.action_stats else None,
        "params": m.params,
        "created_by": m.created_by,
    }


def format_info(info: dict) -> list[str]:
    """The lines ``madp dataset info`` prints for a :func:`dataset_info` result."""
    lines = [f"{info['root']}: {info['num_samples']} samples, N = {info['num_robots']}, {info['format']}, "
             f"schema v{info['schema_version']}, code {info['code_version']}",
             f"  {'split':<6}{'samples':>9}{'episodes':>10}{'shards':>8}{'MB':>10}"]
    for name in ("train", "val", "test"):
        s = info["splits"][name]
        lines.append(f"  {name:<6}{s['samples']:>9}{s['episodes']:>10}{s['shards']:>8}{s['bytes'] / 1e6:>10.1f}")
    lines.append(f"  {info['bytes'] / 1e6:.1f} MB on disk, {info['bytes_per_sample'] / 1e3:.1f} kB per sample")
    st = info["action_stats"]
    if st:
        lines.append(f"  actions (train): mean {st['mean'][0]:+.4f} {st['mean'][1]:+.4f} m/s, "
                     f"std {st['std'][0]:.4f} {st['std'][1]:.4f} m/s over {st['count']} robot-samples")
    lines.append(f"  made by: {info['created_by']}")
    return lines


def verify_dataset(root: os.PathLike | str, on_shard: Optional[Callable[[Path], None]] = None) -> int:
    """Check every shard's size and sha256, then decode every sample and check counts and values.

    Returns the number of samples verified; raises DataError naming the first faulty file.
    """
    root = Path(root)
    m = open_dataset(root)
    m.verify_shards(root, check_sha256=True)
    total = 0
    for split, sp in m.splits.items():
        for shard in sp.shards:
            path = root / shard.file
            n, episodes = 0, set()
            for b in iter_shard(path, m.format):
                if b.num_robots != m.num_robots:
                    raise DataError.at(path, f"holds {b.num_robots} robots per sample, manifest says {m.num_robots}")
                for name in ("actions", "positions", "observations"):
                    if not np.isfinite(getattr(b, name)).all():
                        raise DataError.at(path, f"field '{name}' holds NaN or infinity")
                n += b.num_samples
                episodes.update(np.unique(b.episode_id).tolist())
            if n != shard.num_samples or len(episodes) != shard.num_episodes:
                raise DataError.at(path, f"holds {n} samples in {len(episodes)} episodes, manifest says "
                                         f"{shard.num_samples} in {shard.num_episodes}")
            total += n
            if on_shard:
                on_shard(path)
    return total


def convert_dataset(root: os.PathLike | str, fmt: str, out: os.PathLike | str, overwrite: bool = False) -> Manifest:
    """Re-encode every shard as ``fmt`` into ``out``; the manifest keeps its content (format, file
    names, checksums and sizes change with the encoding).

    Each source shard is checked against the manifest (size, sha256, counts) before it is read, and
    the samples and episodes it decodes to must match it too. ``out`` is locked while it is written;
    ``overwrite`` replaces a dataset there, removing only the manifest, the shards it lists and the
    shards this conversion writes (any other file is refused by name); the leftovers of an
    interrupted conversion (no manifest yet) are simply rewritten."""
    root, out = Path(root), Path(out)
    m = open_dataset(root)
    if fmt not in ("mcap", "parquet"):
        raise SettingError("to", f"expected mcap or parquet, got {fmt!r}")
    if out.resolve() == root.resolve():
        raise DataError.at(out, "must differ from the source dataset directory")
    def target(s: ShardInfo) -> str:
        return str(Path(s.file).with_suffix("." + fmt).as_posix())

    mine = [target(s) for sp in m.splits.values() for s in sp.shards]
    with locked_dir(out):
        if any(p.name != LOCK_FILENAME for p in out.iterdir()):
            interrupted = not (out / MANIFEST_FILENAME).exists() and not foreign_files(out, mine)
            if overwrite:
                clear_owned(out, manifest_files(out) + mine)
            elif not interrupted:  # an interrupted conversion of this dataset is simply redone
                raise DataError.at(out, "is not empty; choose another --out or pass --overwrite")
        splits = {}
        for name, sp in m.splits.items():
            shards = []
            for s in sp.shards:
                src, dst_rel = root / s.file, target(s)
                check_shard(src, s, m.format, num_robots=m.num_robots)
                info = convert_shard(src, out / dst_rel)
                if (info.num_samples, info.num_episodes) != (s.num_samples, s.num_episodes):
                    raise DataError.at(src, f"decodes to {info.num_samples} samples in {info.num_episodes} episodes, "
                                            f"manifest says {s.num_samples} in {s.num_episodes}")
                shards.append(ShardInfo(dst_rel, info.num_samples, info.num_episodes, info.sha256, info.bytes))
            splits[name] = SplitInfo(shards)
        converted = replace(m, format=fmt, splits=splits)
        converted.save(out / MANIFEST_FILENAME)
    return converted

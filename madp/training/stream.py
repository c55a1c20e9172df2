"""Streaming the shards of one split into training, never holding the dataset in memory.

Order of one epoch, a pure function of (seed, epoch) and the manifests:

0. with several datasets (DAgger rounds), the epoch's shard list holds each dataset's shards
   ``weight`` times: ``floor(w)`` full copies plus a draw of ``round(frac(w) · shards)`` of them
   (``default_rng([seed, epoch, 0xDA7A, d])``); one dataset of weight 1 is just its shards;
1. the epoch's shards are permuted (``default_rng([seed, epoch])``);
2. shard j of the permutation goes to stream ``j % S``, where the S = world_size × num_workers
   streams are the (torch.distributed rank, DataLoader worker) pairs — no sample reaches two
   streams;
3. each stream reads its shards in order through a shuffle buffer of ``buffer_size`` samples
   (its own RNG, ``default_rng([seed, epoch, stream])``) and yields exactly ``per_stream`` samples,
   the same number for every stream (the smallest stream's count rounded down to whole batches),
   so ranks stay in lockstep; the few surplus samples of an epoch are skipped, different ones each
   epoch;
4. with datasets of several swarm sizes N, each stream regroups its samples so that every batch
   holds one N (a sample waits for ``batch_size`` of its size); only its last batches mix sizes,
   padded with a ``valid`` mask (:func:`collate_swarms`). One N: the order of step 3 unchanged.

Resuming mid-epoch: the position is (epoch, samples already yielded per stream). A resumed stream
replays its reads and buffer draws up to that point without handing the samples out (decoding
only, no model work), then continues exactly as an uninterrupted one would.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
import torch
from torch.utils.data import IterableDataset, default_collate, get_worker_info

from madp.data_schema import Manifest, iter_shard
from madp.errors import InputError, SettingError

from madp.models.symmetry import AUGMENTATIONS, D4_SIZE, transform_sample


@dataclass(frozen=True)
class StreamPosition:
    epoch: int
    samples_per_stream: int  # already yielded by each stream in this epoch


def epoch_shards(groups: list[list[int]], weights: list[float], seed: int, epoch: int) -> list[int]:
    """The shard indices of one epoch: dataset ``d`` (its shards ``groups[d]``) ``weights[d]`` times."""
    out: list[int] = []
    for d, (shards, w) in enumerate(zip(groups, weights)):
        whole, frac = divmod(float(w), 1.0)
        out += shards * int(whole)
        extra = int(round(frac * len(shards)))
        if extra:
            pick = np.random.default_rng([seed, epoch, 0xDA7A, d]).choice(len(shards), extra, replace=False)
            out += [shards[i] for i in sorted(pick)]
    return out


def stream_plan(counts: list[int], seed: int, epoch: int, num_streams: int,
                shards: list[int] | None = None) -> tuple[list[list[int]], int]:
    """(shard indices per stream, samples per stream) for one epoch over ``shards`` (default: all)."""
    shards = list(range(len(counts))) if shards is None else shards
    if len(shards) < num_streams:
        raise SettingError("num_workers", f"{len(shards)} shards cannot feed {num_streams} streams (ranks x loader "
                           "workers); use fewer workers or ranks")
    order = np.random.default_rng([seed, epoch]).permutation(len(shards))
    streams = [[shards[int(s)] for s in order[i::num_streams]] for i in range(num_streams)]
    per_stream = min(sum(counts[s] for s in st) for st in streams)
    return streams, per_stream


class ShardStream(IterableDataset):
    """Samples of one split as dicts of tensors: ``obs [N, 4, 32, 32]`` float32, ``pos_m [N, 2]``,
    ``actions [N, 2]`` (m/s, unnormalised), and the sample's ``episode_id`` and ``step``.

    ``augment="d4"``: each sample is replaced by one of its 8 images under the world's rotations
    and reflections (:mod:`madp.models.symmetry`), drawn per sample from the stream's seed.

    ``batch_size`` only rounds each stream's count down to whole batches (so every DataLoader
    worker hands out whole batches and every rank the same number).
    """

    def __init__(self, root: str | Path | list, manifest: Manifest | list, split: str, seed: int, batch_size: int = 1,
                 buffer_size: int = 1024, rank: int = 0, world_size: int = 1, augment: str = "none",
                 weights: list[float] | None = None):
        roots = [Path(r) for r in root] if isinstance(root, (list, tuple)) else [Path(root)]
        manifests = list(manifest) if isinstance(manifest, (list, tuple)) else [manifest]
        self.weights = [1.0] * len(roots) if not weights else [float(w) for w in weights]
        if not len(roots) == len(manifests) == len(self.weights):
            raise ValueError("one manifest and one weight per dataset root")
        self.root = roots[0]
        self.paths, self.counts, self.formats, self.groups = [], [], [], []
        for r, m in zip(roots, manifests):
            shards = m.splits[split].shards
            if not shards:
                raise InputError(f"{r}: split '{split}' has no shards")
            self.groups.append(list(range(len(self.paths), len(self.paths) + len(shards))))
            self.paths += [str(r / s.file) for s in shards]
            self.counts += [s.num_samples for s in shards]
            self.formats += [m.format] * len(shards)
        manifest = manifests[0]
        self.seed, self.batch_size, self.buffer_size = seed, batch_size, buffer_size
        self.rank, self.world_size = rank, world_size
        if augment not in AUGMENTATIONS:
            raise SettingError("augment", f"expected one of {list(AUGMENTATIONS)}, got {augment!r}")
        self.augment = augment
        self.world_size_m = float(manifest.params.get("params", {}).get("world_size", 1024.0))
        self.position = StreamPosition(0, 0)

    def set_position(self, position: StreamPosition) -> None:
        """Start the next iteration at ``position`` (set before creating the DataLoader iterator)."""
        self.position = position

    def _plan(self, epoch: int, num_streams: int) -> tuple[list[list[int]], int]:
        shards = epoch_shards(self.groups, self.weights, self.seed, epoch)
        return stream_plan(self.counts, self.seed, epoch, num_streams, shards)

    def samples_per_stream(self, num_workers: int, epoch: int) -> int:
        _, per = self._plan(epoch, self.world_size * max(num_workers, 1))
        return per - per % self.batch_size

    def __iter__(self) -> Iterator[dict]:
        info = get_worker_info()
        workers, worker = (info.num_workers, info.id) if info else (1, 0)
        stream = self.rank * workers + worker
        epoch, skip = self.position.epoch, self.position.samples_per_stream
        streams, per = self._plan(epoch, self.world_size * workers)
        per -= per % self.batch_size
        rng = np.random.default_rng([self.seed, epoch, stream])
        # The D4 element of the k-th sample of this stream's epoch: its own stream of draws, one per
        # sample including skipped ones, so a resumed epoch transforms exactly as an unbroken one.
        aug = np.random.default_rng([self.seed, epoch, stream, 0xD4]).integers(0, D4_SIZE, per) \
            if self.augment == "d4" else None
        for emitted, out in enumerate(self._batched_by_size(self._shuffled(streams[stream], rng))):
            if emitted >= per:
                return
            if emitted >= skip:
                yield self._emit(out, aug, emitted)

    def _shuffled(self, shard_ids: list[int], rng: np.random.Generator) -> Iterator[tuple]:
        """The samples of ``shard_ids`` through the shuffle buffer (one ``rng`` draw per sample out)."""
        buffer: list[tuple] = []
        for sample in self._samples(shard_ids):
            if len(buffer) < self.buffer_size:
                buffer.append(sample)
                continue
            j = int(rng.integers(len(buffer)))
            out, buffer[j] = buffer[j], sample
            yield out
        while buffer:
            yield buffer.pop(int(rng.integers(len(buffer))))

    def _batched_by_size(self, samples: Iterator[tuple]) -> Iterator[tuple]:
        """``samples`` regrouped so that every run of ``batch_size`` holds one swarm size N: a sample
        waits until ``batch_size`` of its size have arrived, and the rest go out at the end, smallest N
        first (those last batches mix sizes; :func:`collate_swarms` pads them). Datasets of one N
        pass through in their order; several N (e.g. swarms of 32 and 128) batch without padding."""
        pending: dict[int, list[tuple]] = {}
        for sample in samples:
            group = pending.setdefault(len(sample[1]), [])
            group.append(sample)
            if len(group) == self.batch_size:
                yield from pending.pop(len(sample[1]))
        for n in sorted(pending):
            yield from pending[n]

    def _emit(self, sample: tuple, aug: np.ndarray | None, k: int) -> dict:
        d = _to_tensors(sample)
        if aug is not None and aug[k]:
            d["obs"], d["pos_m"], d["actions"] = transform_sample(d["obs"], d["pos_m"], d["actions"], int(aug[k]),
                                                                  self.world_size_m)
        return d

    def _samples(self, shard_ids: list[int]) -> Iterator[tuple]:
        for s in shard_ids:
            for b in iter_shard(self.paths[s], self.formats[s]):
                for i in range(b.num_samples):
                    yield b.observations[i], b.positions[i], b.actions[i], b.episode_id[i], b.step[i]


def collate_swarms(samples: list[dict]) -> dict:
    """A batch of samples: stacked as torch's default collate does when they share N; otherwise
    padded to the largest N (``obs``, ``pos_m``, ``actions`` zero there) with ``valid [B, N]`` bool
    marking the real robots. Only the last batches of a stream mix sizes
    (:meth:`ShardStream._batched_by_size`).

    ``obs [B, N, C, S, S]`` comes with the channels innermost in memory (strides of a
    ``[B, N, S, S, C]`` array), the layout the perception CNN computes in: the loader workers pay
    for the transposition, not the training process. Only the memory layout differs from a plain
    stack; the values are the same."""
    sizes = [len(s["pos_m"]) for s in samples]
    b, n = len(samples), max(sizes)
    c, h, w = samples[0]["obs"].shape[1:]
    obs = samples[0]["obs"].new_zeros((b, n, h, w, c))
    for i, (s, k) in enumerate(zip(samples, sizes)):
        obs[i, :k] = s["obs"].permute(0, 2, 3, 1)
    if len(set(sizes)) == 1:
        out = default_collate([{k: v for k, v in s.items() if k != "obs"} for s in samples])
        out["obs"] = obs.permute(0, 1, 4, 2, 3)
        return out
    out = {key: samples[0][key].new_zeros((b, n, *samples[0][key].shape[1:])) for key in ("pos_m", "actions")}
    valid = torch.zeros(b, n, dtype=torch.bool)
    for i, (s, k) in enumerate(zip(samples, sizes)):
        for key in out:
            out[key][i, :k] = s[key]
        valid[i, :k] = True
    out.update(obs=obs.permute(0, 1, 4, 2, 3), valid=valid, episode_id=torch.tensor([s["episode_id"] for s in samples]),
               step=torch.tensor([s["step"] for s in samples]))
    return out


def _to_tensors(sample: tuple) -> dict:
    obs, pos, act, episode, step = sample
    return {"obs": torch.from_numpy(obs.astype(np.float32)), "pos_m": torch.from_numpy(np.array(pos)),
            "actions": torch.from_numpy(np.array(act)), "episode_id": int(episode), "step": int(step)}

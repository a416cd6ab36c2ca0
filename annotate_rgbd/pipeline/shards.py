"""Shards of a batch: the K-th of N disjoint subsets of a manifest's scenes, for one task of a
cluster's job array each (SLURM arrays, GNU parallel).

A scene's shard is a hash of its name, so it depends on nothing else: the same on every run and
machine, and unchanged when scenes are added to the manifest or reordered. The N shards of a
manifest are disjoint and together hold every scene. Pure functions of the scene list.
"""

from __future__ import annotations

import hashlib
from typing import Sequence, TypeVar

from annotate_rgbd.errors import InputError

Scene = TypeVar("Scene")


def parse_shard(text: str) -> tuple[int, int]:
    """Read ``--shard K/N``.

    Parameters
    ----------
    text : str
        ``"K/N"`` with ``1 <= K <= N``.

    Returns
    -------
    (int, int)
        ``(K, N)``.

    Raises
    ------
    InputError
        Not of that form.
    """
    k, sep, n = text.partition("/")
    if not sep or not k.strip().isdigit() or not n.strip().isdigit() or not 1 <= int(k) <= int(n):
        raise InputError(None, f"--shard {text!r}: expected K/N with 1 <= K <= N, e.g. --shard 1/4")
    return int(k), int(n)


def shard_of(name: str, n: int) -> int:
    """The shard (1 to ``n``) of a scene: its name's BLAKE2b hash modulo ``n``, plus 1.

    Parameters
    ----------
    name : str
        The scene's name (a manifest's ``name``, by default its output folder's name).
    n : int
        Number of shards, >= 1.

    Returns
    -------
    int
    """
    digest = hashlib.blake2b(name.encode("utf-8"), digest_size=8).digest()
    return int.from_bytes(digest, "big") % n + 1


def select_shard(scenes: Sequence[Scene], k: int, n: int, name=lambda scene: scene.name) -> list[Scene]:
    """The scenes of shard ``k`` of ``n``, in manifest order.

    Parameters
    ----------
    scenes : sequence
        The manifest's scenes.
    k, n : int
        ``1 <= k <= n``.
    name : callable, optional
        A scene's name (default: its ``name`` attribute).

    Returns
    -------
    list
    """
    return [scene for scene in scenes if shard_of(name(scene), n) == k]

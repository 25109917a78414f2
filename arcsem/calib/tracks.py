"""Tracks: features of several views that show the same 3-D point, from pairwise matches.

Every feature is a node, every verified match an edge; a track is a connected component with two or more
features. A component that holds two features of one view is ambiguous (a wrong match chained it) and is
dropped whole.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .matching import PairMatches

__all__ = ["Observations", "build_tracks"]


@dataclass
class Observations:
    """Flat observation arrays: ``vi [n]`` view, ``pj [n]`` track (point), ``uv [n, 2]`` pixels,
    ``fi [n]`` feature index in its view; ``n_points`` tracks."""

    vi: np.ndarray
    pj: np.ndarray
    uv: np.ndarray
    fi: np.ndarray
    n_points: int

    def __len__(self) -> int:
        return len(self.vi)

    def select(self, keep: np.ndarray) -> Observations:
        """The observations ``keep [n]`` (bool); tracks left with fewer than two views are dropped and
        the track ids renumbered ``0..``."""
        vi, pj, uv, fi = self.vi[keep], self.pj[keep], self.uv[keep], self.fi[keep]
        counts = np.bincount(pj, minlength=self.n_points)
        ok = counts[pj] >= 2
        vi, pj, uv, fi = vi[ok], pj[ok], uv[ok], fi[ok]
        used, new = np.unique(pj, return_inverse=True)
        return Observations(vi, new, uv, fi, len(used))

    def track_lengths(self) -> np.ndarray:
        """``[n_points]`` views per track."""
        return np.bincount(self.pj, minlength=self.n_points)


def build_tracks(matches: list[PairMatches], keypoints: list[np.ndarray]) -> Observations:
    """Tracks from ``matches`` over views with keypoints ``keypoints[v] [K_v, 2]`` (module docstring)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    offsets = np.concatenate([[0], np.cumsum([len(k) for k in keypoints])])
    total = int(offsets[-1])
    if not matches or total == 0:
        return Observations(*(np.zeros(0, int),) * 2, np.zeros((0, 2)), np.zeros(0, int), 0)
    src = np.concatenate([offsets[m.a] + m.ia for m in matches])
    dst = np.concatenate([offsets[m.b] + m.ib for m in matches])
    graph = coo_matrix((np.ones(len(src)), (src, dst)), shape=(total, total))
    _, label = connected_components(graph, directed=False)
    node_view = np.repeat(np.arange(len(keypoints)), np.diff(offsets))
    size = np.bincount(label)
    nodes = np.nonzero(size[label] >= 2)[0]
    lab, view = label[nodes], node_view[nodes]
    # a track with two features in one view is ambiguous: drop it
    pairs = lab.astype(np.int64) * len(keypoints) + view
    uniq, counts = np.unique(pairs, return_counts=True)
    bad_tracks = np.unique(uniq[counts > 1] // len(keypoints))
    keep = ~np.isin(lab, bad_tracks)
    nodes, lab, view = nodes[keep], lab[keep], view[keep]
    used, pj = np.unique(lab, return_inverse=True)
    fi = nodes - offsets[view]
    uv = np.concatenate(keypoints)[nodes].astype(np.float64)
    return Observations(view.astype(np.int64), pj.astype(np.int64), uv, fi.astype(np.int64), len(used))

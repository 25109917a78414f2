"""Colour spread over the stage-1 surface, for what no reference sees.

Colourisation by optimisation (Levin, Lischinski and Weiss 2004: neighbours of similar intensity get similar
colour), moved from the image plane onto the frozen stage-1 surface:

* **nodes**: the specimen pixels of every training view, unprojected with the stage-1 depth and merged into cubic
  cells of ``cell`` world units (about a pixel's footprint), so one node is one patch of surface seen by one or
  more views. A node carries its position, grey value and normal (means over its pixels);
* **edges**: each node to its ``k`` nearest nodes within ``reach`` cells, weighted by
  ``w_ij = exp(-d_ij^2 / 2 s_d^2) exp(-(g_i - g_j)^2 / 2 s_g^2) exp(-(1 - n_i . n_j) / s_n)``: close, alike in grey
  and of one orientation. ``s_g`` is one scale for the scene (``grey_scale``), not Levin's local window variance:
  that variance is large exactly at a part's edge, which leaves the edge's weight near ``exp(-1)``, too weak to
  keep a colour from leaking across the large unseen regions solved here;
* **scribbles**: the nodes holding reference pixels, with their mean reference colour;
* **solve**: every other node's colour is the weighted mean of its neighbours' (the graph Laplacian's harmonic
  solution, ``L_uu x_u = W_us x_s``), found per connected part that holds a scribble. The same solve of each
  scribble colour cluster's indicator gives the probability that a random walk from the node first meets that
  cluster (Grady 2006); a node is **confident** when one cluster has at least ``confidence`` of it. Unconfident
  nodes (between parts of different colour, or far across weak edges) and parts without scribbles get no colour:
  the solve never paints a colour without evidence. A confident node takes the colour of that cluster's
  scribbles as the walk reaches them (the same solve, their colours times the indicator, over the probability),
  so colours vary within a part (a red-to-yellow body) but two parts' colours never blend.

:func:`surface_colors` returns per-pixel colours and validity for every view; the stage-2 pseudo-colour target
takes them where the 2-D pseudo-colours (:mod:`arcsem.colorize.pseudocolor`) have none.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..cameras import Cameras
from ..configs import SurfaceConfig

__all__ = ["SurfaceGraph", "build_graph", "colour_clusters", "harmonic_solve", "surface_colors"]


@dataclass
class SurfaceGraph:
    """Nodes ``[M]`` (position ``[M, 3]``, grey ``[M]``, normal ``[M, 3]``), the symmetric weights (scipy CSR
    ``[M, M]``) and, per view pixel, its node (``node_of [N, H, W]`` long, -1 outside)."""

    pos: np.ndarray
    grey: np.ndarray
    normal: np.ndarray
    weights: object
    node_of: np.ndarray


def _lift(cams: Cameras, depths: Tensor, masks: Tensor):
    """World points ``[P, 3]`` of the masked pixels with depth of every view, their flat indices ``[P]`` into
    ``[N*H*W]`` and the median pixel footprint."""
    valid = masks.bool() & (depths > 0)
    pts = cams.to(dtype=torch.float64).unproject(depths.double())  # [N, H, W, 3]
    flat = valid.reshape(-1).nonzero()[:, 0]
    z = depths.reshape(-1)[flat].double()
    fx = cams.K[:, 0, 0].double()
    view = flat // (depths.shape[1] * depths.shape[2])
    foot = (1.0 / fx[view]) if cams.is_ortho else z / fx[view]
    return pts.reshape(-1, 3)[flat].numpy(), flat.numpy(), float(foot.median()) if len(flat) else 1.0


def build_graph(cams: Cameras, depths: Tensor, masks: Tensor, grey: Tensor, normals: Tensor,
                p: SurfaceConfig | None = None) -> SurfaceGraph:
    """The surface graph of the views ``cams`` (depth ``[N, H, W]``, 0: none; masks ``[N, H, W]``; grey
    ``[N, H, W]`` in [0, 1]; world normals ``[N, H, W, 3]``)."""
    from scipy.sparse import coo_matrix
    from scipy.spatial import cKDTree

    p = p or SurfaceConfig()
    pts, flat, foot = _lift(cams, depths, masks)
    cell = p.cell_px * foot
    node_of = np.full(depths.numel(), -1, dtype=np.int64)
    if len(pts) == 0:
        return SurfaceGraph(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), coo_matrix((0, 0)).tocsr(),
                            node_of.reshape(depths.shape))
    _, inv, count = np.unique(np.floor(pts / cell).astype(np.int64), axis=0, return_inverse=True,
                              return_counts=True)
    inv = inv.reshape(-1)
    node_of[flat] = inv
    M = len(count)

    def mean(x):
        out = np.zeros((M, x.shape[1]))
        np.add.at(out, inv, x)
        return out / count[:, None]

    pos = mean(pts)
    g = mean(grey.reshape(-1)[flat].double().numpy()[:, None])[:, 0]
    n = mean(normals.reshape(-1, 3)[flat].double().numpy())
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    k = min(p.k + 1, M)
    d, j = cKDTree(pos).query(pos, k=k, distance_upper_bound=p.reach * cell, workers=-1)
    d, j = d.reshape(M, k)[:, 1:], j.reshape(M, k)[:, 1:]
    ok = np.isfinite(d)
    i = np.repeat(np.arange(M), k - 1).reshape(M, k - 1)
    jj = np.where(ok, j, 0)
    w = (np.exp(-(d ** 2) / (2 * cell ** 2)) * np.exp(-((g[jj] - g[:, None]) ** 2) / (2 * p.grey_scale ** 2))
         * np.exp(-(1 - (n[jj] * n[:, None]).sum(-1)) / p.normal_scale))
    W = coo_matrix((w[ok], (i[ok], jj[ok])), shape=(M, M)).tocsr()
    return SurfaceGraph(pos, g, n, ((W + W.T) * 0.5).tocsr(), node_of.reshape(depths.shape))


def harmonic_solve(W, known: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Harmonic extension over the graph ``W`` (symmetric CSR ``[M, M]``) of ``values [S, D]`` given at the nodes
    ``known [S]``: ``x [M, D]`` (each unknown node the weighted mean of its neighbours) and ``reached [M]`` bool
    (the node's connected part holds a known node; elsewhere ``x`` is 0)."""
    from scipy.sparse import diags
    from scipy.sparse.csgraph import connected_components
    from scipy.sparse.linalg import spsolve

    M = W.shape[0]
    x = np.zeros((M, values.shape[1]))
    x[known] = values
    _, comp = connected_components(W, directed=False)
    reached = np.isin(comp, np.unique(comp[known]))
    unknown = np.flatnonzero(reached & ~np.isin(np.arange(M), known))
    if len(unknown) == 0:
        return x, reached
    deg = np.asarray(W.sum(1)).reshape(-1)
    L = (diags(deg) - W).tocsr()
    Luu = L[unknown][:, unknown].tocsc()
    rhs = -(L[unknown][:, known] @ values)
    x[unknown] = np.asarray(spsolve(Luu, rhs)).reshape(len(unknown), -1)
    return x, reached


def colour_clusters(colours: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    """Label ``[S]`` of each scribble colour ``[S, 3]`` among at most ``k`` clusters (k-means, k-means++ start)."""
    from scipy.cluster.vq import kmeans2

    k = max(1, min(k, len(np.unique(np.round(colours, 3), axis=0))))
    if k == 1:
        return np.zeros(len(colours), dtype=np.int64)
    _, labels = kmeans2(colours.astype(np.float64), k, minit="++", seed=seed)
    return labels.astype(np.int64)


def surface_colors(cams: Cameras, depths: Tensor, masks: Tensor, grey: Tensor, normals: Tensor,
                   ref_indices: list[int], ref_images: Tensor, p: SurfaceConfig | None = None,
                   graph: SurfaceGraph | None = None, ref_keep: Tensor | None = None) -> tuple[Tensor, Tensor, dict]:
    """Colour of every masked pixel of every view from the references' colours, spread over the surface.

    Args: as :func:`build_graph` (``graph``: built by it already, for these views); ref_indices: ``R`` view indices of the references; ref_images ``[R, H, W, C]``:
        colours, and any further channels to carry alike (e.g. the reference's grey); clustered on the first 3;
        ref_keep ``[R, H, W]`` bool: the reference pixels that scribble (default: all).
    Returns: colours ``[N, H, W, C]`` float32 (0 where invalid), valid ``[N, H, W]`` bool (a confident node) and
    figures (nodes, scribbled nodes, confident share).
    """
    p = p or SurfaceConfig()
    N, H, W = depths.shape
    graph = graph if graph is not None else build_graph(cams, depths, masks, grey, normals, p)
    M = len(graph.grey)
    C = ref_images.shape[-1]
    colours, valid = torch.zeros(N, H, W, C), torch.zeros(N, H, W, dtype=torch.bool)
    ref_nodes = graph.node_of[ref_indices].reshape(-1)
    ref_cols = ref_images.float().reshape(-1, C).numpy().astype(np.float64)
    keep = (ref_nodes >= 0) & (True if ref_keep is None else ref_keep.reshape(-1).numpy())
    if M == 0 or not keep.any():
        return colours, valid, {"nodes": M, "scribbled": 0, "confident": 0.0}
    known, inv = np.unique(ref_nodes[keep], return_inverse=True)
    scribble = np.zeros((len(known), C))
    np.add.at(scribble, inv, ref_cols[keep])
    scribble /= np.bincount(inv, minlength=len(known))[:, None]
    labels = colour_clusters(scribble[:, :3], p.clusters)
    K = int(labels.max()) + 1
    onehot = np.eye(K)[labels]  # [S, K]
    x, reached = harmonic_solve(graph.weights, known, np.concatenate([onehot, (onehot[:, :, None] * scribble[:, None]
                                                                              ).reshape(-1, C * K)], 1))
    prob, best = x[:, :K], x[:, :K].argmax(1)
    # the colour of the best cluster's scribbles as the walk reaches them (never a blend of two clusters)
    col = x[:, K:].reshape(M, K, C)[np.arange(M), best] / np.maximum(prob[np.arange(M), best], 1e-12)[:, None]
    ok = reached & (prob.max(1) >= p.confidence)
    node = torch.from_numpy(graph.node_of)
    hit = node >= 0
    hit[hit.clone()] = torch.from_numpy(ok)[node[hit]]
    colours[hit] = torch.from_numpy(np.clip(col, 0, 1)).float()[node[hit]]
    valid[hit] = True
    return colours, valid, {"nodes": M, "scribbled": len(known), "confident": float(ok.mean())}

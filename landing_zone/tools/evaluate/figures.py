"""Pictures of an evaluation: ROC curves, reliability, and the look inside the CNN.

The look inside follows the paper's Figs. 11-13: the most confident mistakes as cross-sections
with the obstacle marked (:func:`look_inside`), the first layer's filters as z slices
(:func:`plot_filters`) and class models, the inputs that maximise the safe and the unsafe
score (:func:`class_models`, Simonyan et al. 2014). matplotlib is used through its object API
with the Agg canvas.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from landing_zone.judging.net import SafetyNet

if TYPE_CHECKING:
    from landing_zone.tools.evaluate.methods import MethodResult

__all__ = ['confident_mistakes', 'class_models', 'plot_filters', 'plot_roc', 'plot_reliability',
           'look_inside']


def confident_mistakes(p_safe: np.ndarray, labels: np.ndarray, k: int = 6
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the ``k`` unsafe tiles scored safest and the ``k`` safe tiles scored least
    safe, worst first: the most confident false positives and false negatives (those on the
    wrong side of 0.5 are mistakes at that threshold; the rest are the nearest misses)."""
    p = np.asarray(p_safe)
    y = np.asarray(labels)
    unsafe = np.flatnonzero(y == 0)
    safe = np.flatnonzero(y == 1)
    fp = unsafe[np.argsort(-p[unsafe], kind='stable')][:k]
    fn = safe[np.argsort(p[safe], kind='stable')][:k]
    return fp, fn


def class_models(model: SafetyNet, steps: int = 150, lr: float = 0.05, l2: float = 1e-3,
                 seed: int = 0) -> dict[str, np.ndarray]:
    """Inputs that maximise each class score under an L2 penalty (Simonyan et al., 2014).

    Gradient ascent (Adam) on ``s(x) - l2 * ||x||^2``, with ``s`` the logit of P(safe) for
    'safe' and its negative for 'unsafe', the input kept in [-1, 1] (the range the network ever
    sees). It starts from bare flat ground (an occupied layer at the cube's middle, free space
    above, unobserved below) plus a little noise: the all-zero start of the original, here an
    entirely unobserved cube, leaves a trained net's ReLUs silent and the gradient zero. Both
    are optimised as one batch of two: in eval mode the samples do not interact, and one pass
    over two volumes costs about what one over a single volume does.

    Returns:
        {'safe': (S, S, S), 'unsafe': (S, S, S)} float32 volumes.
    """
    side = model.config.input_size
    net = model.float().eval()
    gen = torch.Generator().manual_seed(seed)
    x = 0.05 * torch.randn((2, 1, side, side, side), generator=gen)  # (2, 1, D, H, W)
    x[..., side // 2] += 0.7  # the ground layer (tiles put it at the cube's middle)
    x[..., side // 2 + 1:] -= 0.6  # observed free space above it
    x = x.clamp(-1.0, 1.0).requires_grad_(True)
    sign = torch.tensor([1.0, -1.0])
    opt = torch.optim.Adam([x], lr=lr)
    flags = [p.requires_grad for p in net.parameters()]
    for p in net.parameters():
        p.requires_grad_(False)
    try:
        for _ in range(steps):
            opt.zero_grad()
            logit, _ = net(x)  # (2,)
            objective = (sign * logit).sum() - l2 * (x ** 2).sum()
            (-objective).backward()
            opt.step()
            with torch.no_grad():
                x.clamp_(-1.0, 1.0)
    finally:
        for p, f in zip(net.parameters(), flags):
            p.requires_grad_(f)
    vols = x.detach()[:, 0].numpy().astype(np.float32)
    return {'safe': vols[0], 'unsafe': vols[1]}


def _obstacle_patches(ax: Any, obstacle: dict | None, plane: str, vs: float, pad: int,
                      tile_vox: int) -> None:
    """Outline the obstacle (tile frame params) on an input cross-section in voxel units."""
    if not obstacle:
        return
    from matplotlib.patches import Polygon, Rectangle
    try:
        cx, cy = float(obstacle['x']), float(obstacle['y'])
        dx, dy, dz = (float(v) for v in obstacle['size'])
        yaw = float(obstacle.get('yaw', 0.0))
    except (KeyError, TypeError, ValueError):
        return

    # tile frame [m] -> input voxel index: the tile's core starts at -tile/2 at index pad
    def to_vox(v: np.ndarray) -> np.ndarray:
        return (v + tile_vox * vs / 2) / vs + pad
    c, s = math.cos(yaw), math.sin(yaw)
    corners = np.array([[sx * dx / 2, sy * dy / 2] for sx, sy in
                        ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    world = corners @ np.array([[c, s], [-s, c]]) + [cx, cy]
    vox = to_vox(world)
    ground = pad + tile_vox // 2
    style = dict(fill=False, edgecolor='magenta', linewidth=1.2)
    if plane == 'xy':
        ax.add_patch(Polygon(vox[:, ::-1] - 0.5, closed=True, **style))  # imshow: rows = x
    else:
        axis = 0 if plane == 'xz' else 1
        lo, hi = vox[:, axis].min(), vox[:, axis].max()
        ax.add_patch(Rectangle((ground - 0.5, lo - 0.5), dz / vs, hi - lo, **style))


def _cross_sections(volumes: list[np.ndarray], titles: list[str], path: Path,
                    obstacles: list[dict | None] | None = None, vs: float = 0.05,
                    pad: int = 6, tile_vox: int = 20, suptitle: str = '') -> None:
    """One row per volume: x-z and y-z sections through the cube centre (or the obstacle) and
    an x-y section just above the ground voxel; colours are the input 2 * density - 1."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    n = max(len(volumes), 1)
    fig, axes = plt.subplots(n, 3, figsize=(9, 2.9 * n), squeeze=False)
    for row, vol in enumerate(volumes):
        side = vol.shape[0]
        ob = obstacles[row] if obstacles else None
        ix = iy = side // 2
        if ob:
            try:
                ix = int(np.clip(round((float(ob['x']) + tile_vox * vs / 2) / vs + pad), 0,
                                 side - 1))
                iy = int(np.clip(round((float(ob['y']) + tile_vox * vs / 2) / vs + pad), 0,
                                 side - 1))
            except (KeyError, TypeError, ValueError):
                pass
        kz = min(pad + tile_vox // 2 + 2, side - 1)
        sections = [(vol[:, iy, :], f'x-z at y={iy}', 'xz'),
                    (vol[ix, :, :], f'y-z at x={ix}', 'yz'),
                    (vol[:, :, kz], f'x-y at z={kz}', 'xy')]
        for col, (img, label, plane) in enumerate(sections):
            ax = axes[row, col]
            ax.imshow(img, cmap='RdBu_r', vmin=-1, vmax=1, origin='lower',
                      interpolation='nearest')
            ax.set_title(f'{titles[row]}\n{label}' if col == 0 else label, fontsize=8)
            ax.set_xlabel('z' if plane != 'xy' else 'y', fontsize=7)
            ax.set_ylabel('x' if plane != 'yz' else 'y', fontsize=7)
            ax.tick_params(labelsize=6)
            _obstacle_patches(ax, ob, plane, vs, pad, tile_vox)
    if not volumes:
        axes[0, 0].text(0.5, 0.5, 'none', ha='center', va='center')
    if suptitle:
        fig.suptitle(suptitle, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_filters(model: SafetyNet, path: Path, max_filters: int = 32) -> None:
    """First-layer 3D filters, one row each, as their z slices."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    conv = next((m for m in model.modules() if isinstance(m, torch.nn.Conv3d)), None)
    if conv is None:
        return
    w = conv.weight.detach().float().cpu().numpy()[:max_filters, 0]  # (F, k, k, k)
    f, k = w.shape[0], w.shape[-1]
    lim = float(np.abs(w).max()) or 1.0
    fig, axes = plt.subplots(f, k, figsize=(0.8 * k + 0.5, 0.8 * f + 0.5), squeeze=False)
    for i in range(f):
        for z in range(k):
            ax = axes[i, z]
            ax.imshow(w[i, :, :, z], cmap='RdBu_r', vmin=-lim, vmax=lim, origin='lower',
                      interpolation='nearest')
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(f'z={z}', fontsize=7)
        axes[i, 0].set_ylabel(f'{i}', fontsize=7, rotation=0, labelpad=8)
    fig.suptitle(f'first-layer filters of {model.spec} (x-y slices)', fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_roc(results: list[MethodResult], path: Path, title: str) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 5))
    for r in results:
        ax.plot(r.fpr, r.tpr, label=f'{r.name} (AUC {r.auc:.3f})')
    ax.plot([0, 1], [0, 1], color='grey', linestyle=':', linewidth=1)
    ax.set_xlabel('unsafe tiles accepted (false positive rate)')
    ax.set_ylabel('safe tiles accepted (true positive rate)')
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc='lower right')
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_reliability(results: list[MethodResult], path: Path) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    rs = [r for r in results if r.reliability is not None]
    fig, (ax, axc) = plt.subplots(2, 1, figsize=(5, 6.5), sharex=True,
                                  gridspec_kw={'height_ratios': [3, 1]})
    ax.plot([0, 1], [0, 1], color='grey', linestyle=':', linewidth=1, label='perfect')
    for r in rs:
        rel = r.reliability
        width = float(rel.edges[1] - rel.edges[0])  # equal-width bins
        centres = 0.5 * (rel.edges[:-1] + rel.edges[1:])
        full = rel.count > 0
        ax.plot(rel.confidence[full], rel.frequency[full], marker='o', markersize=3,
                label=f'{r.name} (ECE {r.ece:.3f})')
        axc.bar(centres, rel.count, width=width, alpha=0.5, label=r.name)
    ax.set_ylabel('observed share of safe tiles')
    ax.set_title('reliability of P(safe)', fontsize=9)
    ax.legend(fontsize=7)
    axc.set_xlabel('predicted P(safe)')
    axc.set_ylabel('tiles')
    axc.set_yscale('log')
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# --- the command -------------------------------------------------------------------------------

def look_inside(model: SafetyNet, p_safe: np.ndarray, y: np.ndarray, x: np.ndarray,
                pack: Any, out: Path, vs: float, pad: int, tile_vox: int, k: int = 6) -> None:
    fp, fn = confident_mistakes(p_safe, y, k)
    for idx, name, what in ((fp, 'false_positives.png', 'unsafe judged safe'),
                            (fn, 'false_negatives.png', 'safe judged unsafe')):
        vols = [x[i, 0] for i in idx]
        obstacles = [pack.params[i].get('obstacle') for i in idx]
        wrong = (p_safe[idx] >= 0.5) == (y[idx] == 0)
        titles = [f'scene {int(pack.scene_ids[i])}: P(safe) {p_safe[i]:.3f}'
                  + (' (mistake)' if w else '') for i, w in zip(idx, wrong)]
        _cross_sections(vols, titles, out / name, obstacles, vs, pad, tile_vox,
                        f'most confident mistakes: {what} (obstacle outlined)')
    plot_filters(model, out / 'filters.png')
    cm = class_models(model)
    _cross_sections([cm['safe'], cm['unsafe']], ['class model "safe"', 'class model "unsafe"'],
                    out / 'class_models.png', None, vs, pad, tile_vox,
                    'inputs that maximise each class score (L2-regularised)')

"""Matplotlib figures for the reports (object-oriented API, Agg canvas, no pyplot state)."""

from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from framework import images
from framework.images import NO_SEGMENT_RGB, colorize_segments

DPI = 100
METHOD_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b",
                  "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")


def _new_figure(width: float, height: float, *, layout: str | None = "constrained") -> Figure:
    """A figure on an Agg canvas (no global pyplot state); ``layout=None`` is the fast path."""
    fig = Figure(figsize=(width, height), dpi=DPI, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path) -> None:
    """Write a figure as PNG."""
    fig.savefig(path, format="png", dpi=DPI)


def _set_log_y(ax, values) -> None:
    """Log y axis for positive data, symmetric log otherwise."""
    vals = np.asarray(values, dtype=float)
    vals = vals[np.isfinite(vals)]
    if vals.size and np.all(vals > 0):
        ax.set_yscale("log")
    elif vals.size:
        nz = np.abs(vals[vals != 0])
        ax.set_yscale("symlog", linthresh=float(nz.min()) if nz.size else 1.0)


def plot_convergence(path, costs, *, times=None) -> None:
    """Cost against evaluation index and (when ``times`` is given) cumulative wall time.

    Parameters
    ----------
    path : str or path-like
        PNG to write.
    costs : sequence of float
        Cost of each evaluation.
    times : sequence of float, optional
        Wall time of each evaluation, seconds since the method started, same length as
        ``costs``.
    """
    costs = np.asarray(costs, dtype=float)
    with_time = times is not None and len(times) == len(costs)
    fig = _new_figure(9 if with_time else 4.8, 3.2, layout=None)
    fig.subplots_adjust(left=0.1 if with_time else 0.17, right=0.98, bottom=0.15, top=0.95,
                        wspace=0.3)
    axes = fig.subplots(1, 2 if with_time else 1, squeeze=False)[0]
    marker = "o" if costs.size < 30 else None
    axes[0].plot(np.arange(costs.size), costs, marker=marker, ms=3)
    axes[0].set_xlabel("cost evaluation")
    if with_time:
        axes[1].plot(np.asarray(times, dtype=float), costs, marker=marker, ms=3, color="#d62728")
        axes[1].set_xlabel("wall time (s)")
    for ax in axes:
        ax.set_ylabel("cost")
        _set_log_y(ax, costs)
        ax.grid(True, which="both", alpha=0.3)
    _save(fig, path)


def plot_difference(path, diff: np.ndarray, *, title: str) -> None:
    """Signed difference image on a diverging colour map with a symmetric range and colour bar."""
    diff = np.asarray(diff, dtype=float)
    finite = np.abs(diff[np.isfinite(diff)])
    vmax = float(np.percentile(finite, 99.5)) if finite.size else 0.0
    vmax = vmax or (float(finite.max()) if finite.size else 0.0) or 1.0
    h, w = diff.shape
    img_w = 2.2 * w / h
    fig = _new_figure(img_w + 1.0, 2.5, layout=None)
    frac = img_w / (img_w + 1.0)
    ax = fig.add_axes((0.01, 0.02, frac - 0.02, 0.86))
    im = ax.imshow(diff, cmap="RdBu_r", vmin=-vmax, vmax=vmax, interpolation="nearest")
    ax.set_axis_off()
    ax.set_title(title, fontsize=9)
    cax = fig.add_axes((frac + 0.02, 0.1, 0.06 * 3.5 / (img_w + 1.0), 0.72))
    fig.colorbar(im, cax=cax, extend="both").ax.tick_params(labelsize=7)
    _save(fig, path)


def image_pair(out, stem: str, reference, other, labels: tuple[str, str], title: str) -> list:
    """Figure items of two images of one view, tone-mapped at ``reference``'s exposure, and of their
    signed difference ``other - reference`` (mean over channels) when both exist with one shape;
    ``out(name) -> (path, src)`` names the files ``<stem>_<label>.png`` and ``<stem>_difference.png``."""
    items, exposure = [], images.auto_exposure(reference) if reference is not None else None
    for img, label in ((reference, labels[0]), (other, labels[1])):
        if img is not None:
            path, src = out(f"{stem}_{label}.png")
            images.write_png(path, images.tonemap(img, exposure=exposure))
            items.append((src, label, "pixels"))
    if reference is not None and other is not None and reference.shape == other.shape:
        path, src = out(f"{stem}_difference.png")
        plot_difference(path, (other - reference).mean(axis=-1), title=title)
        items.append((src, "signed difference (mean over channels)"))
    return items


def plot_segments(path, seg_map: np.ndarray, names) -> None:
    """Segment map, one colour per segment, with a legend of the segments present."""
    seg = np.asarray(seg_map)
    names = list(names)
    n = max(len(names), int(seg.max()) + 1 if seg.size else 0)
    labels = names + [f"segment {i}" for i in range(len(names), n)]
    rgb = colorize_segments(seg, n)
    present = np.unique(seg)
    handles = [Patch(color=rgb[seg == i][0] / 255.0, label=labels[i]) for i in present if i >= 0]
    if (present < 0).any():
        handles.append(Patch(color=np.asarray(NO_SEGMENT_RGB) / 255.0, label="none / sky"))
    h, w = seg.shape
    img_w = 2.2 * w / h
    fig = _new_figure(img_w + 1.6, 2.5, layout=None)
    frac = img_w / (img_w + 1.6)
    ax = fig.add_axes((0.01, 0.02, frac - 0.02, 0.86))
    ax.imshow(rgb, interpolation="nearest")
    ax.set_axis_off()
    ax.set_title("segments", fontsize=9)
    fig.legend(handles=handles, loc="center left", bbox_to_anchor=(frac, 0.5), fontsize=7,
               frameon=False)
    _save(fig, path)


def plot_correlation(path, labels, matrix) -> None:
    """Parameter correlation matrix as a heat map on [-1, 1]."""
    mat = np.asarray(matrix, dtype=float)
    n = mat.shape[0]
    size = min(9.0, 2.5 + 0.35 * n)
    fig = _new_figure(size + 1.0, size)
    ax = fig.add_subplot()
    im = ax.imshow(mat, cmap="RdBu_r", vmin=-1, vmax=1, interpolation="nearest")
    ax.set_xticks(range(n), labels, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(n), labels, fontsize=7)
    if n <= 14:
        for (i, j), v in np.ndenumerate(mat):
            ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=6,
                    color="white" if abs(v) > 0.6 else "black")
    fig.colorbar(im, ax=ax, shrink=0.8, label="correlation")
    _save(fig, path)


def plot_spread(path, labels, estimates: dict, *, references=None, title: str = "") -> None:
    """Estimates of every seed, per parameter and method (strip plot with mean ± std).

    Parameters
    ----------
    path : str or path-like
        PNG to write.
    labels : sequence of str
        Parameter labels (x axis).
    estimates : dict
        ``{method: [[estimate per seed] per label]}``; None entries are dropped.
    references : sequence of float or None, optional
        Reference value per label, drawn as a black bar.
    title : str
        Figure title.
    """
    n, methods = len(labels), list(estimates)
    fig = _new_figure(min(16.0, max(5.0, 1.0 + 0.55 * n * max(1, len(methods)) ** 0.5)), 3.8)
    ax = fig.add_subplot()
    width = 0.8 / max(1, len(methods))
    rng = np.random.default_rng(0)
    for k, method in enumerate(methods):
        colour = METHOD_COLOURS[k % len(METHOD_COLOURS)]
        x0 = np.arange(n) - 0.4 + width * (k + 0.5)
        for j, vals in enumerate(estimates[method]):
            v = np.asarray([x for x in vals if x is not None], dtype=float)
            if not v.size:
                continue
            jitter = rng.uniform(-0.25, 0.25, v.size) * width
            ax.scatter(x0[j] + jitter, v, s=14, color=colour, alpha=0.75,
                       label=method if j == 0 else None, zorder=3)
            ax.errorbar(x0[j], v.mean(), yerr=v.std(ddof=1) if v.size > 1 else 0,
                        fmt="_", color=colour, ms=12, capsize=3, zorder=4)
    if references is not None:
        for j, ref in enumerate(references):
            if ref is not None:
                ax.hlines(ref, j - 0.45, j + 0.45, color="black", lw=1.5, zorder=5,
                          label="reference" if j == 0 else None)
    ax.set_xticks(range(n), labels, rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("estimate")
    ax.set_title(title, fontsize=10)
    ax.grid(True, axis="y", alpha=0.3)
    handles, names = ax.get_legend_handles_labels()
    uniq = dict(zip(names, handles))
    ax.legend(uniq.values(), uniq.keys(), fontsize=8, loc="best")
    _save(fig, path)


def plot_bars(path, labels, means, stds, *, ylabel: str, title: str = "") -> None:
    """Bar chart of means with std error bars (log y when values span > 50x)."""
    means = np.asarray([np.nan if m is None else m for m in means], dtype=float)
    stds = np.asarray([0 if s is None or not np.isfinite(s) else s for s in stds], dtype=float)
    fig = _new_figure(max(3.5, 1.2 + 0.9 * len(labels)), 3.2)
    ax = fig.add_subplot()
    colours = [METHOD_COLOURS[i % len(METHOD_COLOURS)] for i in range(len(labels))]
    ax.bar(range(len(labels)), means, yerr=stds, color=colours, capsize=4)
    ax.set_xticks(range(len(labels)), labels, rotation=20, ha="right", fontsize=8)
    pos = means[np.isfinite(means) & (means > 0)]
    if pos.size and pos.max() / pos.min() > 50:
        ax.set_yscale("log")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, axis="y", alpha=0.3)
    _save(fig, path)


def plot_error_time(path, curves: dict, *, target: float | None = None, title: str = "") -> None:
    """Worst (solid) and mean (dashed) |error| against wall time, log-log, one colour per method.

    Parameters
    ----------
    path : str or path-like
        PNG to write.
    curves : dict
        Method name -> list of :class:`reports.convergence.ErrorCurve` (one per run).
    target : float, optional
        The symbolic method's final worst error, drawn as a horizontal line.
    title : str, optional
    """
    fig = _new_figure(7.5, 4.2)
    ax = fig.subplots()
    for i, (method, runs) in enumerate(curves.items()):
        colour = METHOD_COLOURS[i % len(METHOD_COLOURS)]
        for k, c in enumerate(runs):
            t = np.maximum(c.time_s, 1e-3)          # the first iterate can be at t = 0
            ax.plot(t, c.worst, color=colour, lw=1.4, alpha=0.8, label=f"{method} worst" if k == 0 else None)
            ax.plot(t, c.mean, color=colour, lw=1.0, ls="--", alpha=0.8, label=f"{method} mean" if k == 0 else None)
    if target is not None:
        ax.axhline(target, color="k", lw=0.8, ls=":", label="symbolic worst (final)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("wall time since the method started (s)")
    ax.set_ylabel("|estimate − reference|")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    if title:
        ax.set_title(title, fontsize=9)
    _save(fig, path)

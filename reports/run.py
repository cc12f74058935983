"""The report of one run: ``report.md`` and ``report.html`` beside ``results.json``."""

from __future__ import annotations

import json
import math
import re
import time
from pathlib import Path

import numpy as np

from framework import images
from framework.scene.model import EXCLUSION_REASONS
from reports.data import RESULTS_NAME, as_list, check_results, fmt_num, kernel_label, load_results, seed_of
from reports.doc import Doc, staged
from reports.holdout import section_holdout
from reports.plots import image_pair, plot_convergence, plot_correlation, plot_segments
from reports.fit_quality import section_fit_quality
from reports.time_spent import section_time_spent, weights_caption

FILES_DIR = "report_files"
KEY_SETTINGS = ("seed", "spp", "max_bounces", "variant", "device", "views", "budget_renders", "executor")


def _safe(name: str) -> str:
    """A file-name-safe version of ``name``."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", str(name)).strip("_") or "item"


def _short(value, limit: int = 120) -> str:
    """A setting value as short text."""
    text = value if isinstance(value, str) else json.dumps(value, default=str)
    return text if len(text) <= limit else text[: limit - 1] + "…"


class _RunContext:
    """Paths and notes shared by the sections of one run report."""

    def __init__(self, run_dir: Path, results: dict, files: Path):
        self.run_dir = run_dir
        self.results = results
        self.files = files                  # where the figures go until the report is complete
        self.files.mkdir(exist_ok=True)
        self.metrics: list[tuple[str, dict]] = []

    def out(self, name: str) -> tuple[Path, str]:
        """Absolute path and report-relative src of a generated file."""
        return self.files / name, f"{FILES_DIR}/{name}"

    def load_image(self, rel, doc: Doc, what: str):
        """Read an EXR named in results.json; add a note to ``doc`` and return None on failure."""
        if not rel:
            return None
        try:
            return images.read_exr(self.run_dir / rel)
        except Exception as exc:  # noqa: BLE001 - any unreadable image becomes a note
            doc.para(f"{what}: cannot read {rel} ({type(exc).__name__}: {exc})", note=True)
            return None


def _section_overview(doc: Doc, res: dict) -> None:
    """Scene, method and key settings."""
    settings = res.get("settings") if isinstance(res.get("settings"), dict) else {}
    rows = [("Scene", str(res["scene"])), ("Method", str(res["method"])),
            ("Channels", ", ".join(map(str, res["channels"]))),
            ("Origin (survey coordinates of the scene's 0, 0, 0)",
             "none (the scene's own frame)" if res.get("origin") is None else ", ".join(f"{x:.3f}" for x in res["origin"])),
            ("Renders (full ray-tracing passes)", fmt_num(res.get("renders"), digits=0)),
            ("Image RMSE", fmt_num(res.get("image_rmse"), digits=5))]
    rows += [(k, _short(settings[k])) for k in KEY_SETTINGS if k in settings]
    doc.heading("Overview")
    doc.table(["Item", "Value"], rows, left=2)
    others = [(k, _short(v)) for k, v in settings.items() if k not in KEY_SETTINGS]
    if others:
        doc.heading("All settings", level=3)
        doc.table(["Setting", "Value"], others, left=2)


def parameter_rows(res: dict) -> tuple[list, list, list | None]:
    """Columns, rows and column groups of the parameter table in the paper's form.

    Returns
    -------
    tuple
        ``(columns, rows, groups)``; groups is None for one channel. Each channel has
        Ref., Estim., Error (and Std where any parameter has one).
    """
    channels, params = list(res["channels"]), res["parameters"]
    nc = len(channels)
    has_std = any(p.get("std") is not None for p in params)
    has_obs = any("observable" in p or "ill_determined" in p for p in params)
    per_ch = ["Ref.", "Estim.", "Error"] + (["Std"] if has_std else [])
    lead = ["Object", "Param."] + (["Observable"] if has_obs else [])
    columns = lead + per_ch * nc
    groups = None if nc == 1 else [("", len(lead))] + [(c, len(per_ch)) for c in channels]
    rows, previous = [], None
    for p in params:
        obj = str(p["segment"])
        row = [obj if obj != previous else "",
               (kernel_label(p["kernel"]), kernel_label(p["kernel"], html=True))]
        previous = obj
        if has_obs:
            row.append("known" if p.get("known") else "no" if p.get("observable") is False else
                       "ill-determined" if p.get("ill_determined") else "yes")
        cols = [as_list(p.get(k), nc) for k in ("reference", "estimate", "error", "std")]
        for c in range(nc):
            row += [fmt_num(cols[0][c]), fmt_num(cols[1][c]), fmt_num(cols[2][c])]
            row += [fmt_num(cols[3][c])] if has_std else []
        rows.append(row)
    return columns, rows, groups


def mean_abs_error(res: dict) -> float | None:
    """Mean absolute error over every known parameter error and channel, or None."""
    errs = [abs(e) for p in res["parameters"] for e in as_list(p.get("error"), len(res["channels"]))
            if isinstance(e, (int, float))]
    return float(np.mean(errs)) if errs else None


def _section_parameters(doc: Doc, res: dict) -> None:
    """The parameter table (the paper's Tables 1 and 2)."""
    doc.heading("Parameters")
    if not res["parameters"]:
        doc.para("No parameters were estimated.", note=True)
        return
    columns, rows, groups = parameter_rows(res)
    doc.table(columns, rows, groups=groups, left=3 if "Observable" in columns else 2,
              caption=f"Estimates of {res['method']} on {res['scene']}; error = estimate − reference.")
    mae = mean_abs_error(res)
    if mae is not None:
        doc.para(f"Mean absolute error over all known parameters and channels: {fmt_num(mae)}")


def _section_exposure(doc: Doc, res: dict) -> None:
    """The per-view exposure gains (``exposure: per_view``), when results.json has them."""
    rows_in = [e for e in (res.get("exposure") or []) if isinstance(e, dict)]
    if not rows_in:
        return
    nc = len(res["channels"])
    rows = []
    for e in rows_in:
        est, std = as_list(e.get("estimate"), nc), as_list(e.get("std"), nc)
        rows.append([str(e.get("view")), "yes" if e.get("reference") else "no"]
                    + [f"{fmt_num(est[c])} ± {fmt_num(std[c])}" if std[c] is not None else fmt_num(est[c])
                       for c in range(nc)])
    doc.heading("Exposure")
    doc.table(["View", "Reference"] + [f"gain {ch}" for ch in res["channels"]], rows, left=2,
              caption="Per-view, per-channel gains estimated with ρ (pixel = gain · radiance); "
                      "the reference view's are 1 by definition; ± one standard error.")


def _section_illumination(doc: Doc, res: dict) -> None:
    """The unknown emitter scales (``scale: unknown``) and the vignetting profiles, when
    results.json has them."""
    nc = len(res["channels"])
    scales = [e for e in (res.get("illumination") or []) if isinstance(e, dict)]
    if scales:
        rows = []
        for e in scales:
            est, std = as_list(e.get("estimate"), nc), as_list(e.get("std"), nc)
            name = f"{e.get('emitter')}" + (f" ({e['part']})" if e.get("part") else "")
            rows.append([name] + [_pm(est[c], std[c]) for c in range(nc)])
        doc.heading("Illumination")
        doc.table(["Emitter"] + [f"scale {ch}" for ch in res["channels"]], rows, left=1,
                  caption="Unknown emitter scales estimated with ρ: the factor multiplying the light as scene.yaml "
                          "declares it (emitter = its index in scene.yaml's emitters); ± one standard error.")
    lenses = [v for v in (res.get("vignetting") or []) if isinstance(v, dict)]
    if lenses:
        rows = []
        for v in lenses:
            a, a_std = as_list(v.get("estimate"), 3), as_list(v.get("std"), 3)
            rows.append([str(v.get("camera")), "yes" if v.get("known") else "no"]
                        + [_pm(a[i], a_std[i]) for i in range(3)] + [_pm(v.get("corner"), v.get("corner_std"))])
        doc.heading("Vignetting")
        doc.table(["Camera", "Known", "a1", "a2", "a3", "corner V(1)"], rows, left=2,
                  caption="Lens falloff per COLMAP camera, pixel = (1 + a1 r² + a2 r⁴ + a3 r⁶) · radiance; "
                          "± one standard error.")


def _pm(value, std) -> str:
    """``value ± std``, or the value alone without a std."""
    return f"{fmt_num(value)} ± {fmt_num(std)}" if std is not None else fmt_num(value)


def _section_timings(doc: Doc, res: dict) -> None:
    """Render, solve and total times and the render count."""
    timings = res.get("timings_s") if isinstance(res.get("timings_s"), dict) else {}
    order = ["render", "solve", "total"] + [k for k in timings if k not in ("render", "solve", "total")]
    rows = [(f"{k} (s)", fmt_num(timings.get(k), digits=3)) for k in order if k in timings]
    rows.append(("renders", fmt_num(res.get("renders"), digits=0)))
    rows.append(("cost evaluations", str(len(res.get("cost_history") or []))))
    doc.heading("Timings")
    doc.table(["Quantity", "Value"], rows)


def _section_convergence(doc: Doc, ctx: _RunContext) -> None:
    """Cost against evaluation index and wall time (log y)."""
    costs = [c for c in (ctx.results.get("cost_history") or []) if isinstance(c, (int, float))]
    doc.heading("Convergence")
    if not costs:
        doc.para("No cost history recorded.", note=True)
        return
    path, src = ctx.out("convergence.png")
    plot_convergence(path, costs, times=ctx.results.get("cost_times_s"))
    doc.figures([(src, "cost per evaluation (log scale)")])


def _view_panel(doc: Doc, ctx: _RunContext, view: dict, index: int) -> None:
    """Observed, reconstruction, signed difference and segment map of one view."""
    name = str(view.get("name", f"view {index}"))
    stem = f"view{index:02d}_{_safe(name)}"
    doc.heading(f"View {name}", level=3)
    obs = ctx.load_image(view.get("observed"), doc, "observed")
    rec = ctx.load_image(view.get("reconstruction"), doc, "reconstruction")
    items = image_pair(ctx.out, stem, obs, rec, ("observed", "reconstruction"), "reconstruction − observed")
    if obs is not None and rec is not None and obs.shape == rec.shape:
        ctx.metrics.append((name, images.image_metrics(obs, rec)))
    elif obs is not None and rec is not None:
        doc.para(f"shapes differ: observed {obs.shape}, reconstruction {rec.shape}", note=True)
    weights = ctx.load_image(view.get("weights"), doc, "weights") if view.get("weights") else None
    if weights is not None:
        path, src = ctx.out(f"{stem}_weights.png")
        images.write_png(path, np.round(255 * np.clip(weights[..., 0], 0.0, 1.0)).astype(np.uint8))
        items.append((src, weights_caption(weights[..., 0])))
    reasons = _load_reasons(doc, ctx, view)
    if reasons is not None:
        path, src = ctx.out(f"{stem}_excluded.png")
        images.write_png(path, REASON_COLOURS[reasons][..., :3])
        counts = view.get("excluded") or {}
        legend = ", ".join(f"{r} {counts[r]} ({REASON_NAMES[r]})" for r in EXCLUSION_REASONS[1:] if counts.get(r))
        items.append((src, "pixels left out and why: " + (legend or "none") + "; light grey: used"))
    seg = _load_segments(doc, ctx, view.get("segments"))
    if seg is not None:
        path, src = ctx.out(f"{stem}_segments.png")
        plot_segments(path, seg, ctx.results.get("segments") or [])
        items.append((src, "segment map"))
    if items:
        doc.figures(items)


#: RGB of each code of EXCLUSION_REASONS in the report's map, and its colour's name
REASON_COLOURS = np.array([[200, 200, 200], [0, 0, 0], [230, 200, 0], [40, 80, 200], [110, 110, 110],
                           [220, 40, 40], [190, 0, 190]], np.uint8)
REASON_NAMES = dict(zip(EXCLUSION_REASONS, ("light grey", "black", "yellow", "blue", "dark grey", "red", "magenta")))


def _load_reasons(doc: Doc, ctx: _RunContext, view: dict):
    """The view's map of exclusion codes (``excluded_map``), or None (a note when unreadable)."""
    rel = view.get("excluded_map")
    if not rel:
        return None
    try:
        from PIL import Image
        codes = np.asarray(Image.open(ctx.run_dir / rel))
        if codes.ndim != 2 or codes.max(initial=0) >= len(EXCLUSION_REASONS):
            raise ValueError(f"expected a 2-D map of codes below {len(EXCLUSION_REASONS)}, got {codes.shape}")
        return codes
    except Exception as exc:  # noqa: BLE001 - shown in the report
        doc.para(f"excluded: cannot read {rel} ({type(exc).__name__}: {exc})", note=True)
        return None


def _load_segments(doc: Doc, ctx: _RunContext, rel):
    """Read a segment index map (.npy); a note and None on failure."""
    if not rel:
        return None
    try:
        seg = np.load(ctx.run_dir / rel, allow_pickle=False)
        if seg.ndim != 2 or not np.issubdtype(seg.dtype, np.integer) or seg.min() < -1:
            raise ValueError(f"expected a 2-D int map with values >= -1, got {seg.dtype} {seg.shape}")
        return seg
    except Exception as exc:  # noqa: BLE001 - shown in the report
        doc.para(f"segments: cannot read {rel} ({type(exc).__name__}: {exc})", note=True)
        return None


def _section_views(doc: Doc, ctx: _RunContext) -> None:
    """One image panel per view, then the image metrics table."""
    views = [v for v in (ctx.results.get("views") or []) if isinstance(v, dict)]
    doc.heading("Views")
    if not views:
        doc.para("No views recorded.", note=True)
        return
    for i, view in enumerate(views):
        _view_panel(doc, ctx, view, i)
    if ctx.metrics:
        doc.heading("Image metrics", level=3)
        rows = [(n, fmt_num(m["rmse"], digits=5), fmt_num(m["psnr"], digits=2),
                 fmt_num(m["ssim"], digits=4)) for n, m in ctx.metrics]
        doc.table(["View", "RMSE", "PSNR (dB)", "SSIM"], rows,
                  caption="Reconstruction against observed; data range = observed max − min.")


def _section_correlation(doc: Doc, ctx: _RunContext) -> None:
    """Parameter correlation heat map, when results.json has one."""
    corr = ctx.results.get("correlation")
    if not isinstance(corr, dict) or not corr.get("matrix"):
        return
    doc.heading("Parameter correlation")
    matrix = np.asarray(corr["matrix"], dtype=float)
    labels = list(corr.get("labels") or [str(i) for i in range(matrix.shape[0])])
    if matrix.ndim != 2 or matrix.shape[0] != matrix.shape[1] or len(labels) != matrix.shape[0]:
        doc.para(f"correlation matrix of shape {matrix.shape} does not match its labels", note=True)
        return
    if len(labels) > HEATMAP_MAX:
        _strongest_pairs(doc, labels, matrix)
        return
    path, src = ctx.out("correlation.png")
    plot_correlation(path, labels, matrix)
    doc.figures([(src, "parameter correlation")])


#: above this many parameters the correlation is a table of the strongest pairs, not a heat map
HEATMAP_MAX = 24
STRONGEST = 20


def _strongest_pairs(doc: Doc, labels: list, matrix: np.ndarray) -> None:
    """The :data:`STRONGEST` parameter pairs of largest |correlation| (a heat map of hundreds of
    parameters is unreadable)."""
    i, j = np.triu_indices(len(labels), k=1)
    values = matrix[i, j]
    order = [k for k in np.argsort(-np.abs(np.nan_to_num(values))) if np.isfinite(values[k])][:STRONGEST]
    doc.table(["Parameter", "Parameter", "Correlation"],
              [[str(labels[i[k]]), str(labels[j[k]]), fmt_num(values[k])] for k in order], left=2,
              caption=f"The {len(order)} strongest of {len(values)} pairs ({len(labels)} parameters).")


def _section_relit(doc: Doc, ctx: _RunContext) -> None:
    """Relit / reflectance images, when results.json lists some."""
    relit = [r for r in (ctx.results.get("relit") or []) if isinstance(r, dict)]
    if not relit:
        return
    doc.heading("Relit images")
    items = []
    for i, item in enumerate(relit):
        name = str(item.get("name", f"relit {i}"))
        img = ctx.load_image(item.get("image"), doc, name)
        if img is not None:
            path, src = ctx.out(f"relit{i:02d}_{_safe(name)}.png")
            images.write_png(path, images.tonemap(img))
            items.append((src, name, "pixels"))
    if items:
        doc.figures(items)


def write_run_report(run_dir, results: dict | None = None) -> tuple[Path, Path]:
    """Write ``report.md`` and ``report.html`` for one run.

    Parameters
    ----------
    run_dir : str or path-like
        A run folder holding ``results.json`` (``docs/results.md``) and its images.
    results : dict, optional
        The results themselves, when ``results.json`` is not written yet (a run writes it last,
        so that a failing report leaves none behind); default: read from the folder.

    Returns
    -------
    tuple of pathlib.Path
        ``(md_path, html_path)``. Images go to ``<run_dir>/report_files/``.

    Raises
    ------
    ReportError
        If ``results.json`` is missing, unreadable, lacks a required key or holds a field of
        the wrong type; nothing is written then. The report's files appear all at once
        (:func:`reports.doc.staged`).
    """
    start = time.perf_counter()
    run_dir = Path(run_dir)
    res = load_results(run_dir) if results is None else check_results(run_dir / RESULTS_NAME, results)
    seed = seed_of(res)
    doc = Doc(f"{res['method']} on {res['scene']}" + (f" (seed {seed})" if seed is not None else ""))
    with staged(run_dir, (FILES_DIR, "report.md", "report.html")) as tmp:
        ctx = _RunContext(run_dir, res, tmp / FILES_DIR)
        for section in (_section_overview, _section_parameters, _section_exposure, _section_illumination,
                        section_fit_quality, _section_timings, section_time_spent):
            section(doc, res)
        for section in (_section_convergence, _section_views, section_holdout, _section_correlation, _section_relit):
            section(doc, ctx)
        doc.para(f"Report generated in {time.perf_counter() - start:.2f} s.", note=True)
        (tmp / "report.md").write_text(doc.render_md(), encoding="utf-8")
        (tmp / "report.html").write_text(doc.render_html(), encoding="utf-8")
    return run_dir / "report.md", run_dir / "report.html"


def finite_or_none(value):
    """``value`` as float when finite, else None."""
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None

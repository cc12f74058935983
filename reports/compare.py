"""Comparison of finished runs across methods and seeds: ``comparison.md`` / ``.html``."""

from __future__ import annotations

import os
from collections import defaultdict
from pathlib import Path

import numpy as np

from reports.data import (as_list, device_of, find_run_dirs, fmt_num, fmt_pm, kernel_label, load_results,
                          seed_of)
from reports.doc import Doc, link_cell, staged
from reports.holdout import section_holdout_table
from reports.convergence import equal_error_rows, error_curve, observable_set
from reports.plots import plot_bars, plot_error_time, plot_spread
from reports.run import _safe, finite_or_none, mean_abs_error, write_run_report

FILES_DIR = "comparison_files"
BASELINE = "symbolic"


def _mean_std(values) -> tuple[float | None, float | None]:
    """Mean and sample std (ddof=1; None for fewer than 2 values) of the finite values."""
    vals = np.asarray([v for v in values if finite_or_none(v) is not None], dtype=float)
    if not vals.size:
        return None, None
    return float(vals.mean()), float(vals.std(ddof=1)) if vals.size > 1 else None


def _method_order(methods) -> list[str]:
    """The baseline method first, then the others alphabetically."""
    return sorted(set(methods), key=lambda m: (m != BASELINE, m))


def _flat(tree: dict, prefix: str = "") -> dict:
    """``{"a": {"b": 1}}`` -> ``{"a.b": 1}`` (lists kept as values)."""
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _variant_settings(res) -> dict:
    """What makes a run a variant of its method: its method options, the observation and tail
    settings and where it ran (Mitsuba variant, device: times on a CPU and a GPU are not seeds of
    one measurement); not the seed, which repetitions vary, nor the views, grouped apart."""
    s = res.get("settings") or {}
    observe = {k: v for k, v in (s.get("observe") or {}).items() if k != "seed"}
    return _flat({"method": {k: v for k, v in (s.get("method_settings") or {}).items() if k != "name"},
                  "observe": observe, "render": {"tail_bounces": s.get("tail_bounces", 0)},
                  "variant": s.get("variant"), "device": s.get("device")})


def variant_labels(runs) -> list[str]:
    """One label per run: its method, plus ``key=value`` for every setting of
    :func:`_variant_settings` that differs between runs of that method (so that variants of a
    method are compared, not pooled as if they were seeds); the variant with the most common
    values keeps the bare method name."""
    settings = [_variant_settings(res) for _, res in runs]
    labels = []
    for i, (_, res) in enumerate(runs):
        peers = [settings[j] for j, (_, r) in enumerate(runs) if r["method"] == res["method"]]
        diffs = []
        for key, value in sorted(settings[i].items()):
            values = [str(p.get(key)) for p in peers]
            common = max(set(values), key=values.count)
            if len(set(values)) > 1 and str(value) != common:
                diffs.append(f"{key.split('.', 1)[-1] if key.startswith('method.') else key}={value}")
        labels.append(f"{res['method']} ({', '.join(diffs)})" if diffs else str(res["method"]))
    return labels


def _param_keys(runs) -> list[tuple[str, str, int, str]]:
    """(segment, kernel, channel index, channel name) of every parameter, in first-seen order."""
    keys: dict = {}
    for _, res in runs:
        for p in res["parameters"]:
            for c, ch in enumerate(res["channels"]):
                keys.setdefault((str(p["segment"]), str(p["kernel"]), c, str(ch)), None)
    return list(keys)


def _values(runs, key, field: str) -> list:
    """The per-run values of one parameter field for one channel (None where absent)."""
    seg, kernel, c, _ = key
    out = []
    for _, res in runs:
        match = next((p for p in res["parameters"]
                      if str(p["segment"]) == seg and str(p["kernel"]) == kernel), None)
        vals = as_list(match.get(field) if match else None, len(res["channels"]))
        out.append(vals[c] if c < len(vals) else None)
    return out


def _param_label(key, mono: bool, *, html: bool = False) -> str:
    """'wall ρ_d R' style label of a parameter channel."""
    seg, kernel, _, ch = key
    return f"{seg} {kernel_label(kernel, html=html)}" + ("" if mono else f" {ch}")


class _Scene:
    """The runs of one scene and view set, grouped by method variant (:func:`variant_labels`)."""

    def __init__(self, name: str, runs):
        self.name = name
        self.by_method = defaultdict(list)
        for (run_dir, res), label in zip(runs, variant_labels(runs)):
            self.by_method[label].append((run_dir, res))
        self.methods = _method_order(self.by_method)
        for m in self.methods:
            self.by_method[m].sort(key=lambda r: (str(seed_of(r[1])), str(r[0])))
        self.keys = _param_keys(runs)
        self.mono = all(len(res["channels"]) == 1 for _, res in runs)

    def stat(self, method: str, getter) -> tuple[float | None, float | None]:
        """Mean and std over a method's runs of ``getter(results)``."""
        return _mean_std([getter(res) for _, res in self.by_method[method]])


def _total_time(res) -> float | None:
    """Total wall time of a run (seconds)."""
    t = res.get("timings_s")
    return finite_or_none(t.get("total")) if isinstance(t, dict) else None


def _compile_time(res) -> float | None:
    """Seconds of Dr.Jit kernel compilation inside the run's total (``timings_s.compile``)."""
    t = res.get("timings_s")
    return finite_or_none(t.get("compile")) if isinstance(t, dict) else None


def _work_time(res) -> float | None:
    """Total time less Dr.Jit's kernel compilation, which the first run of a process pays for
    every kernel (later runs find them compiled), and less rendering the synthetic observations,
    which the first run of a sweep pays for all (the others read them from the cache)."""
    total, t = _total_time(res), res.get("timings_s")
    observe = finite_or_none(t.get("observe")) if isinstance(t, dict) else None
    return None if total is None else total - (_compile_time(res) or 0.0) - (observe or 0.0)


def _renders(res) -> float | None:
    """Render count of a run."""
    return finite_or_none(res.get("renders"))


def _ratio(value, base) -> str:
    """``value / base`` as '×r', or '—'."""
    if value is None or not base:
        return "—"
    return f"×{value / base:.3g}"


def _section_summary(doc: Doc, scene: _Scene) -> None:
    """Per method: runs, seeds, mean |error|, time and renders with ratios to the baseline."""
    compiled = any(_compile_time(r) is not None for m in scene.methods for _, r in scene.by_method[m])
    base = {name: scene.stat(BASELINE, getter)[0] if BASELINE in scene.methods else None
            for name, getter in (("total", _total_time), ("work", _work_time), ("renders", _renders))}
    rows = []
    for m in scene.methods:
        runs = scene.by_method[m]
        seeds = ", ".join(str(seed_of(r)) for _, r in runs)
        t, r, e = scene.stat(m, _total_time), scene.stat(m, _renders), scene.stat(m, mean_abs_error)
        w = scene.stat(m, _work_time)
        rows.append([m, str(len(runs)), seeds, fmt_pm(*e), fmt_pm(*t, digits=3)]
                    + ([fmt_pm(*scene.stat(m, _compile_time), digits=3), fmt_pm(*w, digits=3)] if compiled else [])
                    + [fmt_pm(*r, digits=1), _ratio(t[0], base["total"])]
                    + ([_ratio(w[0], base["work"])] if compiled else []) + [_ratio(r[0], base["renders"])])
    caption = "Mean ± sample std over runs (seeds)."
    if compiled:
        caption += (" Compile: Dr.Jit's kernel compilation inside the total (timings_s.compile): the first "
                    "run of a process compiles every kernel it launches, the later runs of a sweep find most "
                    "of them compiled, so the total charges that warm-up to whichever method ran first; "
                    "a method that compiles new kernels at every evaluation pays it each time, and it is "
                    "counted there too. Work: the total less compile and less rendering the synthetic "
                    "observations (timings_s.observe, paid by the first run of a sweep, read from the cache "
                    "by the others). Both ratios are shown: of the totals and of the work.")
    doc.table(["Method", "Runs", "Seeds", "Mean |error|", "Total time (s)"]
              + (["Compile (s)", "Work (s)"] if compiled else [])
              + ["Renders", f"Time / {BASELINE}"] + ([f"Work / {BASELINE}"] if compiled else [])
              + [f"Renders / {BASELINE}"], rows, left=3, caption=caption)


def _section_errors(doc: Doc, scene: _Scene) -> None:
    """Per parameter (and channel): reference and each method's error, mean ± std over seeds."""
    rows, previous = [], None
    all_runs = [r for m in scene.methods for r in scene.by_method[m]]
    for key in scene.keys:
        ref = next((v for v in _values(all_runs, key, "reference") if v is not None), None)
        row = [key[0] if key[0] != previous else "",
               (kernel_label(key[1]), kernel_label(key[1], html=True))]
        previous = key[0]
        row += [] if scene.mono else [key[3]]
        row.append(fmt_num(ref))
        row += [fmt_pm(*_mean_std(_values(scene.by_method[m], key, "error")))
                for m in scene.methods]
        rows.append(row)
    lead = ["Object", "Param."] + ([] if scene.mono else ["Ch."])
    doc.table(lead + ["Ref."] + scene.methods, rows, left=len(lead),
              groups=[("", len(lead) + 1), ("Error (mean ± std over seeds)", len(scene.methods))],
              caption="error = estimate − reference.")


def _section_plots(doc: Doc, scene: _Scene, files: Path, rel: str) -> None:
    """Spread of estimates across seeds; runtime and render-count bars."""
    stem = _safe(scene.name)
    all_runs = [r for m in scene.methods for r in scene.by_method[m]]
    labels = [_param_label(k, scene.mono) for k in scene.keys]
    refs = [next((v for v in _values(all_runs, k, "reference") if v is not None), None)
            for k in scene.keys]
    est = {m: [_values(scene.by_method[m], k, "estimate") for k in scene.keys] for m in scene.methods}
    items = []
    if scene.keys:
        plot_spread(files / f"{stem}_spread.png", labels, est, references=refs,
                    title=f"{scene.name}: estimates across seeds")
        items.append((f"{rel}/{stem}_spread.png", "spread of the estimates across seeds"))
    for name, getter, ylabel in (("time", _total_time, "total time (s)"),
                                 ("renders", _renders, "renders")):
        stats = [scene.stat(m, getter) for m in scene.methods]
        plot_bars(files / f"{stem}_{name}.png", scene.methods, [s[0] for s in stats],
                  [s[1] for s in stats], ylabel=ylabel, title=f"{scene.name}: {ylabel}")
        items.append((f"{rel}/{stem}_{name}.png", ylabel))
    doc.figures(items[:1])
    doc.figures(items[1:])


def _section_error_time(doc: Doc, scene: _Scene, files: Path, rel: str) -> None:
    """Worst and mean |error| against time for every method (from results.json ``trace``), and
    each baseline's time to reach the symbolic method's final worst error."""
    only = observable_set([r for _, r in scene.by_method.get(BASELINE, [])]) or None
    curves = {m: [c for c in (error_curve(r, only) for _, r in scene.by_method[m]) if c is not None]
              for m in scene.methods}
    curves = {m: c for m, c in curves.items() if c}
    if not curves:
        doc.para("No run has a trace with references: nothing to plot.")
        return
    rows = equal_error_rows(curves, BASELINE)
    target = rows[0]["target"] if rows else None
    stem = _safe(scene.name)
    plot_error_time(files / f"{stem}_error_time.png", curves, target=target,
                    title=f"{scene.name}: error against time")
    doc.figures([(f"{rel}/{stem}_error_time.png", "worst (solid) and mean (dashed) |error| against time")])
    if rows:
        doc.table(["Method", "Reached / runs", "Time to reach (s)", f"Time / {BASELINE}", "Renders to reach",
                   "Floor (worst |error|)"],
                  [[r["method"], f"{r['reached']} / {r['runs']}",
                    fmt_num(r["time_s"], digits=3) if r["time_s"] is not None
                    else f"not reached in {r['max_renders']} renders / {r['max_time_s']:.3g} s",
                    f"×{r['ratio']:.3g}" if r["ratio"] else "—",
                    fmt_num(r["renders"], digits=0), fmt_num(r["floor"]) + _flatness(r)] for r in rows],
                  left=1, caption=f"Errors over the parameters every {BASELINE} run estimates. "
                  f"Target: the {BASELINE} method's final worst |error| "
                  f"{fmt_num(target)} (median over its runs); time: median over the runs that reach it; "
                  f"floor: median worst |error| over the last 10 % of the iterates, flat when a line through "
                  f"log(worst |error|) over the last 30 % falls less than 10 % per tenth of them.")


def _flatness(row: dict) -> str:
    """`` (flat)``, `` (falling N % per tenth)`` or nothing (too few iterates) for a floor."""
    drop = row.get("drop_per_tenth", float("nan"))
    if row.get("flattened"):
        return " (flat)"
    return "" if drop != drop else f" (falling {100 * drop:.0f} % per tenth)"


def _section_runs(doc: Doc, scene: _Scene, out: Path) -> None:
    """One row per run with a link to its report."""
    rows = []
    for m in scene.methods:
        for run_dir, res in scene.by_method[m]:
            href = Path(os.path.relpath(run_dir / "report.html", out)).as_posix()
            rows.append([m, str(seed_of(res)), fmt_num(_total_time(res), digits=3),
                         fmt_num(_renders(res), digits=0), fmt_num(mean_abs_error(res)),
                         link_cell(run_dir.name, href)])
    doc.table(["Method", "Seed", "Total time (s)", "Renders", "Mean |error|", "Report"], rows,
              left=2)


def _scene_key(res) -> str:
    """Runs are compared per scene and view set: the scene's name and its number of views."""
    n = len((res.get("settings") or {}).get("views") or [])
    return f"{res['scene']}, {n} view{'s' if n != 1 else ''}" if n else str(res["scene"])


def _scene_identity(res) -> str:
    """What tells two scenes of one name apart: the scene's content hash (``settings.scene_hash``),
    else its folder (``settings.scene_dir``, runs written before the hash was recorded)."""
    s = res.get("settings") or {}
    return str(s.get("scene_hash") or s.get("scene_dir") or "")


def group_by_scene(runs) -> tuple[dict[str, list], list[str]]:
    """The runs grouped by scene (content hash) and view set, each group under its title, and one
    note per name that several different scenes share. Runs of different scene folders that
    share a ``name:`` are never pooled as one scene: their titles get ``[<hash>]``."""
    groups: dict[tuple[str, str], list] = defaultdict(list)
    for run in runs:
        groups[(_scene_key(run[1]), _scene_identity(run[1]))].append(run)
    shared = defaultdict(list)
    for key, identity in groups:
        shared[key].append(identity)
    titled, notes = {}, []
    for (key, identity), members in groups.items():
        titled[f"{key} [{identity[:16]}]" if len(shared[key]) > 1 else key] = members
    for key, identities in sorted(shared.items()):
        if len(identities) > 1:
            notes.append(f"{len(identities)} different scenes share the name {key} (content hashes or folders "
                         f"{', '.join(sorted(i[:16] for i in identities))}): compared apart, as {key} [<hash>].")
    return titled, notes


def load_runs(dirs) -> list[tuple[Path, dict]]:
    """Find and load every run under ``dirs``; raises ReportError before anything is written."""
    return [(d, load_results(d)) for d in find_run_dirs(dirs)]


def write_comparison(dirs, *, out=None) -> tuple[Path, Path]:
    """Write ``comparison.md`` and ``comparison.html`` comparing the runs under ``dirs``.

    Parameters
    ----------
    dirs : sequence of str or path-like
        Run folders (holding results.json) or sweep folders (searched recursively).
    out : str or path-like, optional
        Output folder; default the common parent of ``dirs`` (``./report`` when that
        is the file-system root).

    Returns
    -------
    tuple of pathlib.Path
        ``(md_path, html_path)``. Missing per-run reports are generated too.

    Raises
    ------
    ReportError
        On bad input (nothing is written then: every results.json is checked first, and the
        comparison's files appear all at once).
    """
    runs = load_runs(dirs)
    out = Path(out) if out is not None else _default_out(dirs)
    for run_dir, _ in runs:
        if not (run_dir / "report.html").is_file():
            write_run_report(run_dir)
    by_scene, notes = group_by_scene(runs)
    doc = Doc("Comparison of runs")
    doc.para(f"{len(runs)} runs, {len(by_scene)} scene(s); baseline for ratios: {BASELINE}. {_devices(runs)}")
    for note in notes:
        doc.para(note)
    with staged(out, (FILES_DIR, "comparison.md", "comparison.html")) as tmp:
        files = tmp / FILES_DIR              # figures, moved into out/ with the documents
        files.mkdir()
        for name in sorted(by_scene):
            scene = _Scene(name, by_scene[name])
            doc.heading(f"Scene {name}")
            _section_summary(doc, scene)
            doc.heading("Parameter errors", level=3)
            _section_errors(doc, scene)
            section_holdout_table(doc, scene)
            doc.heading("Spread, time and renders", level=3)
            _section_plots(doc, scene, files, FILES_DIR)
            doc.heading("Error against time", level=3)
            _section_error_time(doc, scene, files, FILES_DIR)
            doc.heading("Runs", level=3)
            _section_runs(doc, scene, out.resolve())
        (tmp / "comparison.md").write_text(doc.render_md(), encoding="utf-8")
        (tmp / "comparison.html").write_text(doc.render_html(), encoding="utf-8")
    return out / "comparison.md", out / "comparison.html"


def _devices(runs) -> str:
    """Where the runs rendered (results.json ``settings.variant`` and ``settings.device``): times
    and their ratios hold for that device only."""
    places = sorted({device_of(res) for _, res in runs})
    if len(places) == 1:
        return f"Every run rendered with {places[0]}: the times and ratios below are measured there."
    return (f"The runs rendered on {len(places)} devices ({'; '.join(places)}): a method's runs on each "
            "are a variant of their own (labelled), and times across devices are not comparable.")


def _default_out(dirs) -> Path:
    """The common parent of ``dirs``, or ./report when it is the root."""
    common = Path(os.path.commonpath([str(Path(d).resolve()) for d in dirs]))
    return Path.cwd() / "report" if common == Path(common.anchor) else common

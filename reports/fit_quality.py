"""The run report's table of how well the model explains each material (results.json
``fit_quality``, docs/results.md): a fit judged without ground truth."""
from __future__ import annotations

from reports.data import fmt_num
from reports.doc import Doc


def section_fit_quality(doc: Doc, res: dict) -> None:
    """Per material: its usable pixels, the share the robust weights left out, the kept pixels'
    mean squared standardised residual (chi2, about 1 where the model explains them) and the
    verdict with its reason; nothing when the run has no ``fit_quality`` (rendered observations)."""
    quality = res.get("fit_quality")
    if not isinstance(quality, dict) or not quality:
        return
    doc.heading("How well the model explains each material", level=3)
    rows = []
    for name, q in quality.items():
        if not isinstance(q, dict):
            continue
        verdict = f"**poor**: {q.get('why')}" if q.get("poor") else "explained"
        dropped = q.get("dropped")
        rows.append((name, fmt_num(q.get("pixels"), digits=0),
                     "–" if not isinstance(dropped, (int, float)) else f"{100 * dropped:.0f} %",
                     fmt_num(q.get("chi2"), digits=2), _largest_pull(q), _largest_scale(q), verdict))
    doc.table(["Material", "Pixels", "Left out by the robust weights", "chi2 of the kept pixels",
               "Step of its kept pixels", "Std raised", "Verdict"], rows)
    doc.para("chi2: the mean of (residual / the noise the fit expects there)² over the material's kept pixels "
             "and channels, about 1 where the model explains them. Step of its kept pixels: the largest change "
             "of one of its weights (channel, std) that its own kept pixels alone would make to the estimate. A "
             "material whose robust weights left out more than a tenth of its pixels, whose chi2 exceeds 4, or "
             "whose kept pixels' step exceeds 3 std + 0.005 has its weights flagged ill-determined: its estimate "
             "may follow something the model lacks. Short of that, a weight's std is raised to its step / 1.5 where "
             "that is larger (Std raised: the largest factor): its own pixels and the rest of the data disagree "
             "beyond their noise. The views' pixel-weight images below show which pixels were "
             "left out.", note=True)


def _largest_pull(q: dict) -> str:
    """The material's largest ``pull`` in std: ``+0.014 (4.6 std, diffuse B)``; – without one."""
    pulls, zs = q.get("pull"), q.get("pull_std")
    if not isinstance(pulls, dict) or not isinstance(zs, dict):
        return "–"
    best = None
    for kernel, steps in pulls.items():
        for c, (step, z) in enumerate(zip(steps or [], zs.get(kernel) or [])):
            if isinstance(step, (int, float)) and isinstance(z, (int, float)) and (best is None or abs(z) > abs(best[3])):
                best = (kernel, c, step, z)
    if best is None:
        return "–"
    kernel, c, step, z = best
    channel = "RGB"[c] if c < 3 else str(c)
    return f"{step:+.3f} ({abs(z):.1f} std, {kernel} {channel})"


def _largest_scale(q: dict) -> str:
    """The largest factor the pull's floor raised one of the material's std by: ``x2.4``; – where
    none was raised."""
    scales = [x for row in (q.get("std_scale") or {}).values() for x in (row or [])
              if isinstance(x, (int, float)) and x > 1.0]
    return f"x{max(scales):.1f}" if scales else "–"

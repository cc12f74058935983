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
                     fmt_num(q.get("chi2"), digits=2), verdict))
    doc.table(["Material", "Pixels", "Left out by the robust weights", "chi2 of the kept pixels", "Verdict"], rows)
    doc.para("chi2: the mean of (residual / the noise the fit expects there)² over the material's kept pixels "
             "and channels, about 1 where the model explains them. A material whose robust weights left out "
             "more than a quarter of its pixels, or whose chi2 exceeds 4, has its weights flagged "
             "ill-determined: its estimate may follow something the model lacks. The views' pixel-weight "
             "images below show which pixels were left out.", note=True)

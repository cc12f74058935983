"""Benchmark sizes: the real benchmark and the ``--quick`` toy version."""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Sizes:
    """Every size knob of the benchmark.

    Attributes
    ----------
    name : str
        ``default`` or ``quick``.
    ratio_spps : tuple of int
        Samples per pixel of the pass-vs-render comparison (section 1).
    ratio_reps : int
        Timed repetitions (median) after one warm-up.
    mem_views : tuple of int
        Numbers of views of the serial memory runs (section 2); 0 means all views.
    mem_images : tuple of int
        Image sizes (square, pixels) of the serial memory runs; each with every ``mem_views``.
    mem_dask_views : tuple of int
        Numbers of views of the ``executor=dask`` memory runs (2 workers; empty: skipped).
    mem_dask_image : int
        Image size of the Dask memory runs.
    mem_scene_views : int
        Views of the ``urban_canyon`` variant the memory runs use (street views + the aerial one);
        at least the largest view count.
    mem_spp, mem_observe_spp : int
        ``render.spp`` and ``observe.spp`` of the memory runs.
    cmp_spp, cmp_observe_spp, cmp_budget : int
        ``render.spp``, ``observe.spp``, ``budget.renders`` of the comparison (section 3).
    cmp_budget_all : int
        ``budget.renders`` of the iterative and differentiable runs on all views.
    cmp_budget_all_differentiable : int
        ``budget.renders`` of the differentiable runs on all views. Its curve levels off later
        than the iterative ones' (at 400 renders on all views, 48 px wide, its worst error still
        fell 12 % per tenth, 2026-12-04), so the floor column says "still falling"; 400 was cut to
        200 for the benchmark's hour (the 400-render run alone took 6.3 of its minutes).
    cmp_lr_sweep : tuple of float
        Adam learning rates of the differentiable baseline's sweep on the single view, beside the
        shipped default (empty: no sweep). Cut for the benchmark's hour (two runs of the
        comparison's budget, 2.9 of its minutes, 2026-12-04).
    cmp_single_image, cmp_all_image : int or None
        Image width of every run on the single view / on all views (the cameras scaled, the
        observations rendered at that size); None: the scene's own.
    all_views : int
        Views used as "all views" (0: every view of the scene).
    mat_buildings : tuple of int
        Buildings per side of the ``street_block`` runs (section 5); ``mem_spp`` and
        ``mem_observe_spp`` are their spp, all views. 1, 2, 9, 21: 10 materials (the per-view
        reference), 18 (the small street's targets), 70 (the 66-material targets), 148 (296
        weights, the city block); 4, 8 and 16 were cut for the benchmark's hour (their rows lay
        on the growth laws fitted over the others, 2026-12-03).
    mat_default_buildings : tuple of int
        Buildings per side of the runs with the default method (``method=symbolic``) beside:
        1, 2, 21 (9 and 16 cut for the hour; the 66-material targets then fall on K = 21).
    mat_image : int
        Their image size.
    mat_timeout_s : float
        Seconds each may take before it is stopped (reported as failed).
    extra : tuple of str
        Overrides added to every in-process run.
    mega_spp, mega_reps : int
        Samples per pixel and timed repetitions of the 1920x1080 view (section "megapixel"): 64
        spp, the spp its target is set at (pass 44 s, render 35 s, 2026-12-05: with the warm-up,
        under 3 minutes).
    glossy_spp : int
        ``render.spp`` of the glossy section's fits: a ``glossy(0.05)`` window lit by the sun is
        noisy in the pass (fireflies of next-event estimation through a sharp lobe); measured on
        its 100x100 views, the true model's window weights came out at 32 spp 0.00 / 1.00
        (std 0.15 / 0.20, truth 0.18 / 0.72), at 256 spp 0.22 / 0.66 (std 0.03 / 0.05).
    field_image : int or None
        Width of the "field" section's views: None, the bundled ``urban_canyon_field`` (200);
        else the scene built at that size by its generator (same seed, its photographs' spp).
    field_rows : tuple of str or None
        Labels of :data:`bench.field.VARIANTS` the section runs (None: every one). Cut for the
        hour: the default without the boundary exclusion, and the cubic resampling with the
        pixel footprint (the cubic row with the default footprint shows the resampling's effect);
        then the cubic resampling and each pixel its own box (``footprint=pixel``) too (2026-12-04:
        109 s and 77 s of the section's 11 minutes; both met the targets, they test the loader's
        resampling model, which the tests cover).
    glossy_alphas : tuple of float
        The window roughnesses of the glossy section's α sweep (two models, one pass each): the
        truth 0.05, its neighbours 0.03 and 0.1, and 0.3 far off (0.2 and 0.5 were cut for the
        benchmark's hour; their residuals lay between 0.1's and 0.3's and beyond 0.3's).
    defaults_extra, field_extra : tuple of str
        Overrides added to the runs of the "defaults" and "field" sections (the quick bench
        makes them small; the real one runs the shipped settings).
    geometry_triangles : tuple of int
        Triangle counts of the "geometry" section's tessellated street (convert, load, pass).
    geometry_spp : int
        ``render.spp`` of its timed polynomial pass and path render.
    geometry_reps : int
        Timed repetitions of the load, the pass and the render (the least is kept).
    survey_image : int or None
        Width of the "survey" section's views (the bundled scene box-averaged; None: its own 200).
    survey_turbidity_image : int or None
        Width of the "survey" section's row (d) (a sky of unknown turbidity: its photographs
        re-rendered, three skies fitted): None, ``survey_image``'s; cut to 100 for the hour.
    survey_photo_spp : int
        Samples per pixel of the photographs the "survey" section renders for its turbidity row
        (the bundled photographs have 1024; 256 keeps that render to a few minutes, and the
        fit's std covers the photographs' noise: the sandwich takes the image residual).
    survey_rows : tuple of str
        Keys of :data:`bench.survey.ROWS` the "survey" section runs.
    survey_extra : tuple of str
        Overrides added to the "survey" section's runs (the real one runs the shipped settings).
    misfit_image : int or None
        Width of the "misfit" section's views: None, the bundled ``urban_canyon_misfit`` (200);
        else the scene built at that size (its JPEG photographs cannot be box-averaged).
    misfit_photo_spp : int
        Samples per pixel of the photographs of that build (``misfit_image`` not None).
    misfit_rows : tuple of str
        Keys of :data:`bench.misfit.ROWS` and :data:`bench.misfit.CAR_ROWS` the section runs. Row (d),
        the defaults with ``method.consistency=auto``, was cut for the benchmark's hour (221 s;
        2026-12-04 at 200 px it met every target as row (a) did: RMS z 0.89 against 0.85, worst
        diffuse 0.0112 against 0.0084).
    misfit_extra : tuple of str
        Overrides added to the "misfit" section's runs (the real one runs the shipped settings;
        its alignment rows need ``method.refine`` >= 1).
    holdout_image : int or None
        Width of the "holdout" section's views (the field scene built at that size, the survey's
        photographs box-averaged; None: their own 200). At 40 the field's windows are too few
        pixels: measured, the default method's window weights went to diffuse 0.82-0.90,
        specular 0 (the held-out RMSE 1.77x the floor's; 1.07x at 50).
    holdout_budget_cut : int
        The "holdout" section divides the comparison's budgets on all views of the iterative and
        the differentiable baselines by this: 16 and 33 renders. Measured at 50 pixels and a cut of
        16 (25 and 50 renders): the section took 12.2 min on the shared machine, its runs 9.6
        CPU minutes, the differentiable baseline's 93 and 130 of them; the iterative one spent 14
        and 15 of its 25 renders (one finite-difference gradient: it stops before a second would
        pass the budget), as it does with 16.
    holdout_extra : tuple of str
        Overrides added to the "holdout" section's runs (the real one runs the shipped settings).
    """

    name: str = "default"
    ratio_spps: tuple = (16, 64, 256)
    ratio_reps: int = 3
    mem_views: tuple = (1, 4, 16)
    mem_images: tuple = (100, 200)
    mem_dask_views: tuple = (4, 16)
    mem_dask_image: int = 200
    mem_scene_views: int = 16
    mem_spp: int = 32
    mem_observe_spp: int = 128
    cmp_spp: int = 32
    cmp_observe_spp: int = 256
    cmp_budget: int = 300
    cmp_budget_all: int = 200
    cmp_budget_all_differentiable: int = 200
    cmp_lr_sweep: tuple = ()
    cmp_single_image: int | None = 100
    cmp_all_image: int | None = 48
    all_views: int = 0
    mat_buildings: tuple = (1, 2, 9, 21)
    mat_default_buildings: tuple = (1, 2, 21)
    mat_image: int = 200
    mat_timeout_s: float = 1800.0
    extra: tuple = field(default_factory=tuple)
    mega_spp: int = 64
    mega_reps: int = 1
    glossy_spp: int = 256
    glossy_alphas: tuple = (0.03, 0.05, 0.1)
    defaults_extra: tuple = field(default_factory=tuple)
    field_extra: tuple = field(default_factory=tuple)
    field_image: int | None = 100
    field_rows: tuple | None = (
        "naive (gains 1, every pixel, L2)", "+ per-view exposure", "+ masks and saturation",
        "default (+ robust Cauchy, cluster std, bias correction, alignment)",
        "default, pixel sandwich std (method.std=sandwich)", "default without the bias correction (method.bias=none)",
        "default without the alignment (method.align=none)")
    geometry_triangles: tuple = (20_000, 200_000, 2_000_000)
    geometry_spp: int = 16
    geometry_reps: int = 5
    survey_image: int | None = None
    survey_turbidity_image: int | None = 100
    survey_photo_spp: int = 256
    survey_rows: tuple = ("a", "b", "c", "d")
    survey_extra: tuple = field(default_factory=tuple)
    misfit_image: int | None = None
    misfit_photo_spp: int = 16
    misfit_rows: tuple = ("a", "b", "c", "e")
    misfit_extra: tuple = field(default_factory=tuple)
    holdout_image: int | None = 50
    holdout_budget_cut: int = 24
    holdout_extra: tuple = field(default_factory=tuple)
    variant: str = "llvm"


DEFAULT = Sizes()
#: the tests' sizes (``--quick``): every code path of a section, in seconds. The survey's quick
#: runs trace two bounces, take no bias correction and two robust rounds: each solve projects the
#: largest connected component of G (of 3,624 monomials at three bounces: the scales, the lens and the
#: gains raise the degree; its size does not shrink with the image), once per round and per half
#: refit, which made row (d) 91 of the section's 122 s (measured 2026-12-05, loaded machine; 19 s
#: with one round's worth, 4-5 s at two bounces). At two bounces every weight is ill-determined;
#: the light's scales and the lens, what the section measures, are not. The misfit's quick run
#: keeps the car row (e): the defaults on photographs, as row (a), with the car the model lacks;
#: the survey's leaves out row (a), a plain run on a variant :func:`bench.survey.declared_variant`
#: builds (tested alone).
QUICK = Sizes(name="quick", ratio_spps=(4,), ratio_reps=1, mem_views=(1, 2), mem_images=(32,),
              mem_dask_views=(2,), mem_dask_image=32,
              mem_spp=4, mem_observe_spp=8, cmp_spp=4, cmp_observe_spp=16, cmp_budget=20,
              cmp_budget_all=14, cmp_budget_all_differentiable=14, cmp_single_image=40, cmp_all_image=40, all_views=2, mat_buildings=(1, 2), mat_default_buildings=(1,), mat_image=32, mat_timeout_s=300.0,
              extra=("method.solver.starts=1",),
              mega_spp=2, glossy_spp=4, glossy_alphas=(0.05, 0.3), defaults_extra=("render.spp=4", "observe.spp=16", "method.refine=1"),
              field_extra=("render.spp=4", "method.refine=0", "method.irls.iterations=2"), field_image=40,
              geometry_triangles=(2_000, 20_000), geometry_spp=4, geometry_reps=1,
              survey_image=40, survey_turbidity_image=None, survey_photo_spp=4, survey_rows=("b", "c", "d"),
              survey_extra=("render.spp=4", "method.refine=0", "render.tail_bounces=0", "render.max_bounces=2",
                            "method.bias=none", "method.irls.iterations=2"),
              misfit_image=40, misfit_photo_spp=8, misfit_rows=("e",),
              misfit_extra=("render.spp=4", "method.refine=1", "render.tail_bounces=0", "method.irls.iterations=2"),
              holdout_image=20,
              holdout_extra=("method.refine=0", "render.tail_bounces=0", "method.robust=none", "method.bias=none",
                             "method.align=none"))

"""The options of ``method=symbolic`` (and of its presets ``symbolic_paper`` and ``lambertian_prior``).

One frozen dataclass, built once from the method's config group (:func:`framework.options.build`);
each option's default and description are on its field here (``framework/conf/method/symbolic.yaml``
and docs/cli.md's table are generated from them; the presets' YAML files change some defaults).
Every ``auto`` is decided for a problem in one place, :mod:`methods.symbolic.loop.resolved`.
"""
from __future__ import annotations

from dataclasses import dataclass

from framework.errors import ConfigError
from framework.brdf_kernels import KERNEL_SELECTION
from framework.options import choice, either, flag, number, option
from framework.relight import RelightOptions
from methods._common import StartOptions

ROBUST_LOSSES = ("none", "cauchy", "huber")


@dataclass(frozen=True)
class SolverOptions:
    """``method.solver.*``: the exact solve of the polynomial cost."""

    algorithm: str = option(
        "`SQP`: Newton steps on the exact Hessian of the polynomial cost, each an exact quadratic "
        "program under the bounds and Σρ ≤ 1 (quadprog); the others are nlopt's algorithms (all take "
        "the per-segment Σρ ≤ 1 constraints). The joint cost only, like `starts`, `max_eval`, `ftol_rel` "
        "and `precondition`: with `method.cost=per_segment` they are refused away from their defaults",
        choice("SQP", "LD_SLSQP", "LD_MMA", "LD_CCSAQ"), default="SQP")
    starts: int | str = option(
        "starts per channel and parameter block: the initial guess, then seeded random feasible "
        "points; `auto`: 4 for blocks of at most 32 parameters, 1 above (where measured, the random "
        "starts of large blocks found nothing and cost most of the solve)",
        either("auto", number(1, integer=True)), default="auto")
    max_eval: int = option("evaluations per start (`SQP`: iterations per start)", number(1, integer=True),
            default=2000)
    xtol_rel: float = option(
        "nlopt's relative tolerance on the (preconditioned) weights; `SQP` stops when no weight steps "
        "more than this; the per-segment sweeps stop when no weight moves more than this", number(0.0), default=1e-08)
    ftol_rel: float = option(
        "relative tolerance on the cost's decrease (the joint cost)", number(0.0), default=1e-12)
    precondition: bool = option(
        "nlopt only: solve in coordinates where the cost's Hessian is about the identity (3-5 times "
        "fewer evaluations)", flag(), default=True)


@dataclass(frozen=True)
class IrlsOptions:
    """``method.irls.*``: the robust reweighting rounds."""

    iterations: int = option("cap on the robust rounds (one solve each)", number(1, 100, integer=True), default=10)
    tol: float = option("the robust rounds stop when no weight or gain moves more than this", number(0.0),
            default=0.001)


@dataclass(frozen=True)
class SymbolicOptions(StartOptions):
    """``method.*`` of the symbolic family (``method.tail_bounces`` is the framework's:
    :mod:`framework.config` resolves ``render.tail_bounces=auto`` to it)."""

    kernels: tuple[str, ...] | None = option(
        "the kernels to estimate; the others are treated as absent (`[diffuse]` is the paper's "
        "Lambertian setting, Table 1). An unknown name is refused with the list of registered kernels "
        "(`diffuse`, `specular`, `glossy(α)` with α in (0, 1]; quote it on the command line: "
        "`method.kernels='[diffuse,\"glossy(0.2)\"]'`), as is a list that selects none of the scene's "
        "kernels", KERNEL_SELECTION, default="all")
    prob_floor: float = option(
        "least probability of choosing each kernel of a segment at a path vertex, so the polynomial "
        "is unbiased for every ρ, not only near the guess", number(0.0, 1.0), default=0.1)
    gram: str = option(
        "`cross`: the Gram matrix from two independent halves of the samples, G = ½(AᵀB + BᵀA), "
        "unbiased; `plain`: G = AᵀA, which shrinks the estimates at low spp", choice("cross", "plain"),
                default="cross")
    psd: bool = option("project G onto the positive semi-definite matrices before the solve", flag(), default=True)
    cost: str = option(
        "`joint`: one L2 cost over every pixel (the paper's eq. 6), minimised exactly; `per_segment`: "
        "the estimating equations of each segment's own pixels (the pixels whose centre sees it; a "
        "view's exposure gain owns its view's pixels), solved together by block Gauss-Seidel with the "
        "light between segments kept in the polynomial: a segment the kernels cannot reproduce then "
        "keeps its misfit in its own weights instead of biasing the segments it lights. Both are "
        "consistent when the kernels are right (the per-segment fit is a little less efficient); a "
        "segment no pixel sees is held at its guess and reported unobservable; standard errors by the "
        "sandwich of estimating equations (`method.std=residual` is refused with it). results.json "
        "`cost`, `per_segment`", choice("joint", "per_segment"), default="joint")
    std: str = option(
        "the standard error reported: `sandwich` covers the image noise and the Monte Carlo noise of "
        "the polynomial's coefficients (H⁺MH⁺, M from every pixel's term of the cost gradient, with "
        "the two half-sample passes); `residual` counts the image residual only (too small along "
        "weakly constrained directions); `cluster`: the sandwich with the scores summed within "
        "squares of neighbouring pixels of one segment in one view, sized from the residuals' measured "
        "autocorrelation (results.json `std_clusters`), so that misfit shared by neighbouring pixels "
        "(resampled or compressed photographs, misregistration) counts once; see results.md; `auto`: "
        "`cluster` for photographs (a scene's `images/`, any encoding; joint cost), `sandwich` for "
        "observations the run renders itself",
        choice("auto", "sandwich", "residual", "cluster"), default="auto")
    std_device: str = option(
        "where the `sandwich` and `cluster` std form their per-pixel scores' products with the "
        "coefficients (a pass over every stored coefficient per weight; the scores' outer products "
        "stay on the host, in BLAS): `device` on the run's Dr.Jit device (a `cuda_*` variant's GPU, "
        "an `llvm_*` one's CPU threads), `host` with scipy; `auto`: `device` on a `cuda_*` variant, "
        "`host` on an `llvm_*` one, where scipy's are faster (2 cores, all views: the std 1.8-2.0 s on the "
        "host against 2.8 s through Dr.Jit on urban_canyon, 5.5-5.8 s against 13.7-15.4 s on "
        "urban_canyon_survey; docs/design-notes.md; results.json `options_resolved`). Both give the same "
        "values (the same sums in the same order); with "
        "more than 64 weights the scores are sparse and formed on the host either way",
        choice("auto", "device", "host"), default="auto")
    refine: int = option(
        "cap on further passes, each re-rendered at the previous estimate (one render each): the "
        "tail's linearisation and the kernel selection move to the estimate", number(0, 8, integer=True), default=3)
    refine_tol: float = option(
        "refinement stops once no weight moved more than `refine_tol` + z_n √2 std between two passes: "
        "a pass cannot settle closer than its Monte Carlo noise, and z_n (1.96 for one weight, 3.82 for "
        "384) is the bound all n compared weights keep with probability 0.95 when only that noise moves "
        "them; weights without a finite std, which the data do not pin, are not waited for; results.json "
        "`refine_moves` (the largest move in units of that bound), `refine_stopped`",
        number(0.0), default=0.005)
    align: str = option(
        "views aligned to the model between refinement passes (needs `refine` >= 1): each observed "
        "image is registered to the prediction at the pass's estimate by a small rotation of its camera "
        "(Gauss-Newton over the fit's pixel weights), and the next pass renders the corrected camera; "
        "`shift`: pitch and yaw (to first order a sub-pixel image shift), `rotation`: and roll. A "
        "correction above `align_max_px`, ill-conditioned or within its noise is not applied; its "
        "precision is that of the pass's prediction (about 0.03 px on a 64x64 view at 256 spp, 0.15 px "
        "at 16 spp). results.json `alignment`. `auto`: `rotation` for photographs (a scene's "
        "`images/`, any encoding) when `refine` >= 1, else `none` (on the bundled misfit scene, poses 0.5-1 px off, it took the "
        "RMS z from 1.90 to 0.86; on the field scene, whose poses are right, it moved one camera of nine, by "
        "0.03-0.1 px, at 200 px and seeds 0 and 1; BENCHMARKS.md sections 7 and 11)", choice("auto", "none", "shift", "rotation"),
                default="auto")
    align_max_px: float = option(
        "largest correction `align` accepts, in pixels of image motion (at the principal point; the "
        "roll's at the image corner)", number(0.0, lo_open=True), default=3.0)
    align_min_px: float = option(
        "smallest correction `align` applies, in pixels of image motion (as `align_max_px`): on the "
        "bundled field scene, whose poses are right, corrections of 0.03-0.09 px passed the "
        "significance test at 3-5 standard errors and turned right cameras back and forth between "
        "passes (unaligned its RMS z was 1.20 and 1.77 at seeds 0 and 1; aligned without this floor "
        "1.90 and 4.05, with it 2.30 and 1.78: docs/design-notes.md); a "
        "surveyed pose that is 0.5-1 px off is corrected by the first registration", number(0.0), default=0.1)
    exposure: str = option(
        "`scene`: as scene.yaml's `photometry` says (with `exposure: per_view`, one gain per view and "
        "channel solved jointly with ρ, results.json `exposure`); `known`: gains 1", choice("scene", "known"),
                default="scene")
    weights: str = option(
        "`scene`: leave out the pixels the scene marks (masks, saturated and black-clipped pixels, "
        "pixels outside the delivered image after undistortion); `none`: every pixel counts",
        choice("scene", "none"), default="scene")
    robust: str = option(
        "robust reweighting of the pixels (IRLS from the stored coefficients, no render) against "
        "objects the model lacks; `auto`: `cauchy` for photographs (8/16-bit images, pixel weights or "
        "per-view exposure), `none` for linear radiance", choice("auto", *ROBUST_LOSSES), default="auto")
    consistency: str = option(
        "with robust reweighting and at least 3 views, `auto` weighs each pixel whose model point "
        "two or more other views see by how far its relative residual departs from theirs at that "
        "point (a Cauchy weight; objects the model lacks, such as a parked car, disagree between "
        "views whatever share of a segment they cover), before the first solve and after each "
        "robust round; pixels without two other views keep the per-pixel robust weights; `none`: "
        "per-pixel robust weights only (the default: on the tiny scene with a van over 60 % of the "
        "ground in one of 4 views, the per-pixel weights, whose scale includes each pixel's Monte Carlo "
        "variance, erred 0.009-0.018 and `auto` 0.015-0.020, seeds 0-2). results.json "
        "`field.consistency`", choice("auto", "none"), default="none")
    footprint: str = option(
        "`resampled`: a view whose photographs the loader resampled from a distorted camera renders "
        "each pixel over the source pixels its interpolation weighs (each a source pixel's "
        "parallelogram in the pinhole image, drawn with the interpolation's weight), so the prediction "
        "carries the interpolation's blur, which the mirror kernel's weight would otherwise absorb; "
        "`pixel`: each pixel's own box (on the bundled field scene the window's ρ_s then reads "
        "0.013-0.018 lower and its ρ_d 0.010-0.014 higher, BENCHMARKS.md section 7)", choice("resampled", "pixel"),
                default="resampled")
    boundary: int | str = option(
        "leave out pixels within this many pixels of a change of segment, where a pixel mixes two "
        "materials and a sub-pixel error of the geometry or the pose weighs most; `auto`: 1 when some "
        "view has a distorted camera, else 0 (on the bundled field scene, with the footprint, the "
        "window's worst ρ_d error is 0.008 with 1 and 0.010 with 0, BENCHMARKS.md section 7)",
        either("auto", number(0, 8, integer=True)), default="auto")
    bias: str = option(
        "`richardson`: the pass keeps each pixel's samples as four independent quarters, the last "
        "pass is fitted again as two passes of half the spp, and the estimate extrapolated to "
        "2ρ̂_n - ρ̂_{n/2}, which removes the solve's finite-spp bias at order 1/spp (the inverse of a "
        "noisy Gram matrix, noisy robust weights); needs `render.spp` a multiple of 4 and "
        "`gram=cross`; twice the stored coefficients, three solves of the last pass; results.json "
        "`spp_bias`. `none`: the estimate as solved. `auto`: `richardson` for photographs (the field "
        "path) when spp is a multiple of 4, else `none` (on small rendered scenes the correction's own "
        "noise outweighs the bias; on the survey scene it doubled the worst errors, BENCHMARKS.md section "
        "10: see methods/symbolic/loop/richardson.py)", choice("auto", "none", "richardson"), default="auto")
    irls: IrlsOptions = option("the robust rounds", default_factory=IrlsOptions)
    memory_mb: float = option(
        "sets the tile size of the pass: its event buffers take a third of it, and the per-pixel "
        "sums of a tile are done in chunks that take at most an eighth of that (Dr.Jit's allocation "
        "of a view's tiles, power-of-two rounded, was measured at most 0.86 times it with a cache, at "
        "4 to 256 spp and 16 to 512 MiB; docs/design-notes.md). "
        "With a cache, each tile's per-pixel coefficients go to the cache as they are rendered and are "
        "read back one tile at a time, so a large view costs disk, not memory; with `cache.dir=null` "
        "they are held in memory. It does not bound the solve: on the field path (pixel weights, gains, "
        "robust rounds, a lens, unknown light) the run keeps the memory its arrays free for the next "
        "ones until its last fit, so its resident size stays at its high-water mark until then "
        "(docs/design-notes.md, fresh pages)", number(0.0, lo_open=True), default=512)
    solver: SolverOptions = option("the solve", default_factory=SolverOptions)
    relight: RelightOptions = option("relit images", default_factory=RelightOptions)

    def __post_init__(self):
        if self.align_min_px >= self.align_max_px:
            raise ConfigError(f"method.align_min_px={self.align_min_px:g} must be below method.align_max_px="
                              f"{self.align_max_px:g}: lower align_min_px or raise align_max_px")
        if self.align in ("shift", "rotation") and self.refine == 0:
            raise ConfigError(f"method.align={self.align} registers the views between refinement passes: set "
                              "method.refine to at least 1, or method.align=none")
        if self.bias == "richardson" and self.gram != "cross":
            raise ConfigError("method.bias=richardson refits the pass's quarters through the cross Gram: set "
                              "method.gram=cross, or method.bias=none")
        if self.cost == "per_segment" and self.std in ("residual", "cluster"):
            raise ConfigError(f"method.std={self.std} is the joint cost's formula: with method.cost=per_segment "
                              "use method.std=sandwich, or method.cost=joint")

"""A later pass of a process launches only kernels an earlier one compiled (llvm_ad_rgb).

What made a second, identical pass compile again (found by diffing the kernels' LLVM IR): the
environment emitter's registry id written into the kernel as a literal (it depends on which
emitters are alive), unit BSDFs loaded anew by each integrator (their instances enter the
kernel), and numpy tables mapped at addresses whose alignment varies.
"""
import framework.render.backend

framework.render.backend.set_variant("llvm_ad_rgb")

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from framework.render.arrays import ALIGNMENT, device_array  # noqa: E402
from framework.render import kernel_bsdf as KB  # noqa: E402
from framework.render.kernel_bsdf import unit_bsdf  # noqa: E402
from methods.symbolic.trace.integrator import PolynomialPathIntegrator  # noqa: E402

T = mi.ScalarTransform4f


def _scene():
    """A diffuse-or-mirror plane under a constant sky, seen from above: camera rays, next-event
    estimation and emitter hits all meet the environment."""
    return mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 8, "height": 8, "rfilter": {"type": "box"}}},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 2.0, 3.0]}},
        "plane": {"type": "rectangle", "to_world": T().scale(1000)},
    }, optimize=False, parallel=False)


def _compiled(fn) -> list[int]:
    """The sizes of the kernels ``fn()`` launched that were not in this process's kernel cache."""
    was = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    try:
        fn()
        return [k.get("size") for k in dr.kernel_history()
                if k.get("type") == dr.KernelType.JIT and (not k.get("cache_hit") or k.get("cache_disk"))]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, was)


def _environment_id(scene) -> int:
    return int(dr.reinterpret_array(mi.UInt32, mi.EmitterPtr(scene.environment()))[0])


def test_a_second_pass_compiles_nothing():
    """Two passes over two identical scenes whose environments have other registry ids, the
    same emitters alive (Dr.Jit specialises a call on how many instances there are): a spare
    emitter holds id 1 and the first scene's environment takes 2; then a second spare takes
    2, the first is freed, and the second scene's environment takes 1. The second pass launches
    only kernels the first compiled."""
    env_ids, spares = [], [mi.load_dict({"type": "constant"})]

    def one_pass():
        scene = _scene()
        env_ids.append(_environment_id(scene))
        integ = PolynomialPathIntegrator.create([(scene.shapes()[0], 0)], [[("diffuse", 0), ("specular", 1)]],
                                                2, np.full((2, 3), 0.5), max_bounces=2)
        integ.coefficients_sparse(scene, spp=4, seed=0)

    one_pass()
    spares.append(mi.load_dict({"type": "constant"}))
    spares.pop(0)
    assert _compiled(one_pass) == []
    assert env_ids[0] != env_ids[1]          # the case this guards against did arise


def test_unit_bsdf_is_loaded_once():
    """Each form once per process, and both at the first call for a kernel (a form loaded later
    adds a BSDF instance, and so a case, to every virtual call on BSDFs compiled after it)."""
    assert unit_bsdf("diffuse", two_sided=True) is unit_bsdf("diffuse", two_sided=True)
    assert unit_bsdf("diffuse") is not unit_bsdf("diffuse", two_sided=True)
    one_sided = unit_bsdf("glossy(0.35)")
    assert KB._UNITS[(mi.variant(), "glossy(0.35)")] == (one_sided, unit_bsdf("glossy(0.35)", two_sided=True))


def test_device_array_kernel_does_not_depend_on_the_address():
    """The same expression on arrays 4 bytes apart in memory (one of them not 64-byte aligned):
    one kernel. Without the aligned copy Dr.Jit maps numpy's memory and compiles two."""
    buf = np.arange(4097, dtype=np.float32)
    a, b = buf[:-1], buf[1:]
    assert (a.ctypes.data % ALIGNMENT == 0) + (b.ctypes.data % ALIGNMENT == 0) <= 1
    scale = dr.opaque(mi.Float, 3.0)
    first = _compiled(lambda: dr.eval(device_array(mi.Float, a) * scale + 0.25))
    assert _compiled(lambda: dr.eval(device_array(mi.Float, b) * scale + 0.25)) == []
    assert len(first) <= 1
    np.testing.assert_array_equal(device_array(mi.Float, b).numpy(), b)
    np.testing.assert_array_equal(device_array(mi.UInt32, [3, 1, 2]).numpy(), [3, 1, 2])


def test_device_array_errors():
    with pytest.raises(TypeError, match="flat"):
        device_array(mi.Point2f, np.zeros((2, 3)))
    with pytest.raises(TypeError, match="element type"):
        device_array(mi.Float16, np.zeros(3))

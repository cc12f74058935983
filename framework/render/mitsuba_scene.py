"""From the scene model to a Mitsuba scene, keeping segment identity.

Mitsuba merges meshes whose BSDFs are equal (seen with mitsuba 3.9: five segments with identical
placeholder BSDFs became one shape), so the scene is loaded with
``optimize=False`` and every mesh stays its own shape with a known segment. Cameras become
``perspective`` sensors with a box filter (pixel-exact comparison); BSDFs are the exact kernel
sums of :func:`framework.render.kernel_bsdf.forward_bsdf`, whose weights :meth:`MitsubaScene.set_weights`
writes in place through ``mi.traverse`` (no reload).
"""
from __future__ import annotations

import numpy as np

from framework import brdf_kernels as K
from framework.render.arrays import device_array
from framework.render.envmap import TO_WORLD
from framework.render.kernel_bsdf import forward_bsdf, weight_keys
from framework.scene import Camera, Scene


#: Mitsuba renders the scene's N_max reflections with ``max_depth = N_max + 1`` (``max_depth = 1`` renders emitters only, ``2`` direct light).
def max_depth_for(max_bounces: int) -> int:
    return -1 if max_bounces < 0 else max_bounces + 1


def sensor_dict(camera: Camera, *, spp: int, channels: tuple[str, ...]) -> dict:
    """A Mitsuba ``perspective`` sensor equivalent to a COLMAP pinhole camera (box filter).

    Conversion checked to 1e-6 on rays and 0.04 px on a rendered sphere: ``to_world = inv([R|t]) @ diag(-1, -1, 1, 1)``,
    ``fov = 2 atan(w / 2f)`` along x, principal point offsets ``(w/2 - cx)/w``, ``(h/2 - cy)/h``.
    """
    import mitsuba as mi
    T = np.eye(4)
    T[:3] = camera.cam_from_world
    to_world = np.linalg.inv(T) @ np.diag([-1.0, -1.0, 1.0, 1.0])
    w, h = camera.width, camera.height
    return {
        "type": "perspective",
        "to_world": mi.ScalarTransform4f(to_world.tolist()),
        "fov": float(np.degrees(2 * np.arctan(w / (2 * camera.f)))),
        "fov_axis": "x",
        "principal_point_offset_x": (w / 2 - camera.cx) / w,
        "principal_point_offset_y": (h / 2 - camera.cy) / h,
        "near_clip": 1e-3,
        "sampler": {"type": "independent", "sample_count": int(spp)},
        "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                 "pixel_format": "luminance" if channels == ("Y",) else "rgb"},
    }


def emitter_dict(e, channels: tuple[str, ...]) -> dict | None:
    """Mitsuba dict of a non-area emitter (area emitters ride on their meshes)."""
    import mitsuba as mi
    if e.type == "constant":
        return {"type": "constant", "radiance": K.spectrum(e.radiance, channels)}
    if e.type == "directional":
        return {"type": "directional", "direction": [float(x) for x in e.direction],
                "irradiance": K.spectrum(e.irradiance, channels)}
    if e.type == "envmap":
        return {"type": "envmap", "bitmap": mi.Bitmap(np.ascontiguousarray(e.image, np.float32)),
                "scale": float(e.scale), "to_world": mi.ScalarTransform4f(TO_WORLD.tolist())}
    return None


#: Emitter types that are light from infinity: Mitsuba renders one of them per scene.
ENVIRONMENT_TYPES = ("envmap", "constant")


def environments(scene: Scene) -> list[int]:
    """Indices into ``scene.emitters`` of the environments (``envmap``, ``constant``, a sunsky's sky)."""
    return [j for j, e in enumerate(scene.emitters) if e.type in ENVIRONMENT_TYPES]


def summed_environment(emitters, channels: tuple[str, ...]) -> dict:
    """One Mitsuba environment emitting the sum of several (each at its scale): Mitsuba renders one
    environment per scene. Envmaps must share their image size (checked when the scene is read,
    :mod:`framework.render.checks`); a ``constant`` becomes a uniform image of that size."""
    import mitsuba as mi
    images = [e for e in emitters if e.type == "envmap"]
    if not images:
        return {"type": "constant", "radiance": K.spectrum(sum(e.radiance for e in emitters), channels)}
    shape = images[0].image.shape
    total = np.zeros(shape, np.float64)
    for e in emitters:
        total += e.scale * e.image if e.type == "envmap" else np.broadcast_to(e.radiance, shape)
    return {"type": "envmap", "bitmap": mi.Bitmap(np.ascontiguousarray(total, np.float32)),
            "to_world": mi.ScalarTransform4f(TO_WORLD.tolist())}


def _mesh_shape(scene: Scene, i: int):
    """A ``mi.Mesh`` from numpy arrays, with its segment's BSDF and its area emitter, if any."""
    import drjit as dr
    import mitsuba as mi
    m = scene.meshes[i]
    props = mi.Properties()
    if m.segment is None:
        bsdf = {"type": "diffuse", "reflectance": 0.0}          # emits only: absorbs what it gets
    else:
        bsdf = forward_bsdf(list(scene.segments[m.segment].kernels), scene.channels)
    props["bsdf"] = mi.load_dict(bsdf)
    if m.radiance is not None:
        props["emitter"] = mi.load_dict({"type": "area", "radiance": K.spectrum(m.radiance, scene.channels)})
    mesh = mi.Mesh(f"mesh_{i}", len(m.vertices), len(m.faces), props=props, has_vertex_normals=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = dr.ravel(mi.Point3f(m.vertices.T.astype(np.float32)))
    params["faces"] = dr.ravel(mi.Vector3u(m.faces.T.astype(np.uint32)))
    params.update()
    return mesh


class MitsubaScene:
    """A loaded Mitsuba scene of some views of a :class:`Scene`, with segment bookkeeping.

    Parameters
    ----------
    scene : Scene
    cameras : list of Camera
        The views; sensor ``i`` of the Mitsuba scene is ``cameras[i]``.
    spp : int
        Samples per pixel of each sensor's sampler.
    integrator : dict, optional
        Mitsuba integrator dict (default ``path`` with ``max_depth=-1``).

    Notes
    -----
    Every kernel weight starts at 0 (a black scene): call :meth:`set_weights` before rendering.
    """

    def __init__(self, scene: Scene, cameras: list[Camera], *, spp: int, integrator: dict | None = None):
        import mitsuba as mi
        self.model = scene
        self.cameras = list(cameras)
        d = {"type": "scene", "integrator": integrator or {"type": "path", "max_depth": -1}}
        for i, cam in enumerate(self.cameras):
            d[f"sensor_{i}"] = sensor_dict(cam, spp=spp, channels=scene.channels)
        summed = environments(scene) if len(environments(scene)) > 1 else []
        if summed:
            d["emitter_environment"] = summed_environment([scene.emitters[j] for j in summed], scene.channels)
        for j, e in enumerate(scene.emitters):
            ed = emitter_dict(e, scene.channels)
            if ed is not None and j not in summed:
                d[f"emitter_{j}"] = ed
        for i in range(len(scene.meshes)):
            d[f"mesh_{i}"] = _mesh_shape(scene, i)
        # one thread: objects get Dr.Jit registry ids in creation order, and Mitsuba's ``path``
        # writes the environment's id into its kernel as a literal; loaded in parallel, the id
        # (and so the kernel) varied from run to run of a process, each compiling it again
        self.scene = mi.load_dict(d, optimize=False, parallel=False)
        self.params = mi.traverse(self.scene)
        by_id = {s.id(): s for s in self.scene.shapes()}
        #: (mi.Shape, segment index or -1) for every mesh, in scene.meshes order
        self.shape_segments = [(by_id[f"mesh_{i}"], -1 if m.segment is None else m.segment)
                               for i, m in enumerate(scene.meshes)]
        #: (traverse key, segment, kernel) of every kernel weight of every mesh
        self._weight_slots = [(f"mesh_{i}.bsdf.{key}", m.segment, k)
                              for i, m in enumerate(scene.meshes) if m.segment is not None
                              for k, key in zip(scene.segments[m.segment].kernels,
                                                weight_keys(scene.segments[m.segment].kernels))]
        #: with several environments, the one Mitsuba renders (their sum), else None
        self.environment = next((e for e in self.scene.emitters() if e.id() == "emitter_environment"), None)
        #: ``(j, mi.Emitter)`` of each environment summed into :attr:`environment`, built outside the
        #: scene: what each contributes in a direction (the polynomial pass splits the sum by them)
        self.environment_parts = [(j, mi.load_dict(emitter_dict(scene.emitters[j], scene.channels)))
                                  for j in summed]

    def emitter_objects(self, j: int) -> list:
        """The ``mi.Emitter`` objects of ``scene.emitters[j]``: the emitter itself, or for an area
        emitter the area light of each of its meshes; none for an environment summed into
        :attr:`environment` (its light is that sum's, split by :attr:`environment_parts`)."""
        if self.model.emitters[j].type == "area":
            shapes = [shape for (shape, _), mesh in zip(self.shape_segments, self.model.meshes) if mesh.emitter == j]
            return [shape.emitter() for shape in shapes if shape.emitter() is not None]
        return [e for e in self.scene.emitters() if e.id() == f"emitter_{j}"]

    def weight_keys(self, parameters) -> list[list[str]]:
        """Per parameter: the ``mi.traverse`` keys of its weight, one in every mesh of its segment."""
        index = {(p.segment, p.kernel): p.index for p in parameters}
        out: list[list[str]] = [[] for _ in parameters]
        for key, segment, kernel in self._weight_slots:
            j = index.get((segment, kernel))
            if j is not None:
                out[j].append(key)
        return out

    def weight_value(self, values):
        """An opaque Dr.Jit value of the weights' type (``Color3f`` for rgb, ``Float`` for mono)
        holding ``values`` (one number per channel).

        Opaque, because a literal is compiled into the kernels that read it: every new set of
        weights would compile a new render kernel (0.2 s on the CPU, 97 % of a GPU render).
        """
        import drjit as dr
        kind = type(self.params[self._weight_slots[0][0]])
        value = kind(*[float(x) for x in values]) if len(values) > 1 else kind(float(values[0]))
        dr.make_opaque(value)
        return value

    def set_weights(self, rho: np.ndarray, parameters) -> None:
        """Write ρ (P, C) of ``parameters`` into every mesh's BSDF; kernels not listed get 0."""
        self.assign_weights([self.weight_value(row) for row in np.asarray(rho, dtype=float)], parameters)

    def assign_weights(self, values: list, parameters) -> None:
        """Write one Dr.Jit value per parameter (numbers, or differentiable variables) into every
        mesh of its segment; the weights of kernels not in ``parameters`` are set to 0.

        This is the one path from ρ to the Mitsuba scene: every method, the observations and the
        relighting write their weights through it.
        """
        written = {}
        for value, keys in zip(values, self.weight_keys(parameters)):
            for key in keys:
                written[key] = value
        if not self._weight_slots:
            return
        zero = self.weight_value(np.zeros(len(self.model.channels)))
        for key, _, _ in self._weight_slots:
            self.params[key] = written.get(key, zero)
        self.params.update()

    def render(self, view: int = 0, *, spp: int, seed: int, integrator=None) -> np.ndarray:
        """Render sensor ``view``; returns (H, W, C) float32 numpy."""
        import mitsuba as mi
        img = mi.render(self.scene, sensor=view, spp=spp, seed=seed, integrator=integrator)
        out = np.array(img, dtype=np.float32)
        return out.reshape(out.shape[0], out.shape[1], -1)[..., : len(self.model.channels)]

    def pixel_centre_rays(self, view: int = 0, pixels: np.ndarray | None = None):
        """``mi.Ray3f`` through the centre of the ``pixels`` (row-major indices; default all, in
        order) of sensor ``view``."""
        import mitsuba as mi
        cam = self.cameras[view]
        if pixels is None:
            pixels = np.arange(cam.width * cam.height)
        y, x = np.divmod(np.asarray(pixels), cam.width)
        pos = mi.Point2f(device_array(mi.Float, (x + 0.5) / cam.width),
                         device_array(mi.Float, (y + 0.5) / cam.height))
        ray, _ = self.scene.sensors()[view].sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
        return ray

    def centre_hits(self, view: int = 0):
        """``(ray, si, segment)``: the pixel-centre rays of sensor ``view`` (:meth:`pixel_centre_rays`),
        their first intersections and the ``(H·W,)`` int32 segment each hits (-1: sky or emitter only)."""
        import drjit as dr
        import mitsuba as mi
        ray = self.pixel_centre_rays(view)
        si = self.scene.ray_intersect(ray)
        ids = np.array(dr.reinterpret_array(mi.UInt32, si.shape))
        table = {int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0]): seg for s, seg in self.shape_segments}
        uniq, inverse = np.unique(ids, return_inverse=True)
        return ray, si, np.array([table.get(int(u), -1) for u in uniq], dtype=np.int32)[inverse]

    def segment_map(self, view: int = 0) -> np.ndarray:
        """(H, W) int32 segment index seen through each pixel centre (-1: sky or emitter only)."""
        cam = self.cameras[view]
        return self.centre_hits(view)[2].reshape(cam.height, cam.width)


def segment_maps(scene, cameras) -> dict[str, np.ndarray]:
    """View name -> ``(H, W)`` int32 segment seen through each pixel centre (-1: sky or emitter
    only), for every camera of ``cameras`` (:meth:`MitsubaScene.segment_map`)."""
    ms = MitsubaScene(scene, list(cameras), spp=1)
    return {c.name: ms.segment_map(i) for i, c in enumerate(cameras)}

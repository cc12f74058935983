"""The car scene builder (``scenes/urban_canyon_car.py``): the misfit street with an unmasked red
car at each curb, one of them on the asphalt in every street view.

One build of 40 x 40 photographs at 4 spp (the misfit scene's pipeline, whose determinism
tests/scenes/test_misfit_scene.py checks): the model is urban_canyon_field's, no masks, the red
cars' share of the asphalt in every street view (measured at that size by the builder) and none
in the aerial view; and the bundled folder's truth.
"""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from scenes import BUNDLED_DIR
from scenes import urban_canyon_car as car

SIZE, SPP = 40, 4
STREET = [f"street_{i:03d}.jpg" for i in range(8)]


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    return car.build(tmp_path_factory.mktemp("car") / "urban_canyon_car", image=SIZE, spp=SPP)


def _truth(folder: Path) -> dict:
    return yaml.safe_load((folder / "truth.yaml").read_text())


def test_model_is_the_field_scenes(built):
    """scene.yaml is urban_canyon_field's but for the name (the car is in the photographs only);
    no masks; the photographs load."""
    from framework.scene import load_scene

    ours = yaml.safe_load((built / "scene.yaml").read_text())
    theirs = yaml.safe_load((BUNDLED_DIR / "urban_canyon_field" / "scene.yaml").read_text())
    assert ours.pop("name") == "urban_canyon_car" and theirs.pop("name") == "urban_canyon_field"
    assert ours == theirs
    assert not (built / "masks").exists()
    scene = load_scene(built)
    assert sorted(c.name for c in scene.cameras) == sorted(STREET + ["aerial_000.jpg"]) and scene.images is not None


def _check_cars(truth: dict, low: float, high: float) -> None:
    c = truth["car"]
    assert c["masked"] is False and c["origins"] == [list(o) for o in car.CARS] and len(c["boxes"]) == 2
    assert c["materials"]["car_paint"] == car.PAINT
    assert c["views"] == STREET and c["asphalt_share"]["aerial_000.jpg"] == 0.0
    for name in STREET:
        assert low <= c["asphalt_share"][name] <= high, (name, c["asphalt_share"][name])
        assert c["pixels"][name] > 0


def test_a_red_car_on_the_asphalt_in_every_street_view(built):
    """Every street view sees a car over 10-40 % of its asphalt at 40 px (the bundled 100 px:
    17.9-27.0 %), the aerial view none; the paint is the red of :data:`car.PAINT`."""
    _check_cars(_truth(built), 0.10, 0.40)
    assert "every street view" in (built / "README.md").read_text()


def test_bundled_truth():
    """The bundled folder (100 px) holds what the builder promises: both cars unmasked, one over
    17-27 % of the asphalt in every street view (measured 0.179-0.270), none in the aerial view,
    the misfit scene's pose offsets of 0.5-1 px."""
    folder = BUNDLED_DIR / "urban_canyon_car"
    truth = _truth(folder)
    assert truth["image_size"] == [100, 100] and not (folder / "masks").exists()
    _check_cars(truth, 0.17, 0.28)
    assert all(0.5 <= p["px"] <= 1.0 for p in truth["pose"].values())

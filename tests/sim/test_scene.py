import numpy as np
import pytest

from rgbd_envmap.errors import InvalidInputError
from sim.scene import FLAG_BITS, Texture, load_scene, scene_from_dict


def test_office_has_every_kind_of_surface_the_sensors_care_about(office):
    flags = {f for o in office.objects for f in o.flags}
    assert flags == {"emissive", "shiny", "dark"}
    names = {o.name for o in office.objects}
    assert {"ceiling_lamp", "screen", "window", "whiteboard", "dark_cabinet", "panel_red", "panel_green", "panel_blue"} <= names
    assert np.all(np.isfinite(office.virtual_object_position))


def test_office_timeline_removes_an_object_and_dims_the_lamp(office):
    box = office.object("removed_box")
    assert box.visible_at(5.99) and not box.visible_at(6.0)
    assert office.change_times() == [6.0]
    lamp = office.object("ceiling_lamp")
    assert lamp.scale_at(7.9) == 1.0 and lamp.scale_at(8.0) == pytest.approx(0.4)


def test_emitters_exceed_one(office):
    for name in ("ceiling_lamp", "window"):
        o = office.object(name)
        top = o.radiance if o.radiance is not None else o.texture.colours
        assert np.max(top) > 1.0


def test_empty_scene_loads():
    scene = load_scene("empty")
    assert scene.objects == ()


def test_texture_checker_gradient_patches():
    checker = Texture("checker", [[1, 1, 1], [0, 0, 0]], (2, 2))
    s = np.array([0.25, 0.75, 0.25, 0.75])
    t = np.array([0.25, 0.25, 0.75, 0.75])
    np.testing.assert_array_equal(checker.sample(s, t)[:, 0], [1, 0, 0, 1])
    grad = Texture("gradient", [[0, 0, 0], [2, 4, 6]])
    np.testing.assert_allclose(grad.sample(np.zeros(3), np.array([0.0, 0.5, 1.0])), [[0, 0, 0], [1, 2, 3], [2, 4, 6]])
    patches = Texture("patches", np.arange(18).reshape(6, 3), (3, 2))
    # (s, t) = (0.9, 0.9) is column 2 of row 1 → colour index 1 * 3 + 2 = 5.
    np.testing.assert_array_equal(patches.sample(np.array([0.9]), np.array([0.9]))[0], [15, 16, 17])


@pytest.mark.parametrize(
    "spec, match",
    [
        ({"name": "a", "shape": "torus", "radiance": [1, 1, 1]}, "unknown shape"),
        ({"name": "a", "shape": "sphere", "centre": [0, 0, 0], "radius": 1, "radiance": [1, 1, 1], "flags": ["glowing"]}, "unknown flags"),
        ({"name": "a", "shape": "sphere", "centre": [0, 0, 0], "radius": 1, "radiance": [1, -1, 1]}, "radiance"),
        ({"name": "a", "shape": "sphere", "centre": [0, 0, 0], "radius": 1, "radiance": {"texture": "checker", "colours": [[1, 1, 1], [0, 0, 0]]}}, "quads only"),
        ({"name": "a", "shape": "quad", "corner": [0, 0, 0], "u": [1, 0, 0], "v": [0, 1, 0], "radiance": {"texture": "plaid", "colours": [[1, 1, 1]]}}, "unknown"),
    ],
)
def test_bad_object_specs_raise_clear_errors(spec, match):
    with pytest.raises(InvalidInputError, match=match):
        scene_from_dict({"objects": [spec]})


def test_duplicate_names_and_unknown_scene_raise():
    quad = {"shape": "quad", "corner": [0, 0, 0], "u": [1, 0, 0], "v": [0, 1, 0], "radiance": [1, 1, 1]}
    with pytest.raises(InvalidInputError, match="unique"):
        scene_from_dict({"objects": [{"name": "a", **quad}, {"name": "a", **quad}]})
    with pytest.raises(InvalidInputError, match="known scenes are .*office"):
        load_scene("no_such_scene")


def test_flag_bits_are_distinct_powers_of_two():
    bits = list(FLAG_BITS.values())
    assert len(set(bits)) == len(bits) and all(b & (b - 1) == 0 for b in bits)


def test_office_dark_is_lit_with_a_table_under_the_object_and_emitters_in_openings():
    from sim.raycast import SceneRaycaster

    scene = load_scene("office_dark")
    assert scene.is_lit and all(o.lit for o in scene.objects)
    emitters = {o.name for o in scene.objects if o.emits}
    assert emitters == {"window", "lamp_bulb", "laptop_screen"}
    assert all("emissive" in scene.object(n).flags for n in emitters)
    # the window outshines the lamp's light in total power (Le × area), the bulb is far brighter per m²
    power = {n: float(scene.object(n).emission.mean()) * trimesh_area(scene.object(n)) for n in emitters}
    assert power["window"] > 3 * power["lamp_bulb"] > 0
    assert scene.object("lamp_bulb").emission.max() > 10 * scene.object("window").emission.max()
    # the virtual object sits 5 cm above the table top
    rc = SceneRaycaster(scene, bake=False)
    down = rc.cast(scene.virtual_object_position, np.array([[0.0, 0.0, -1.0]]), 0.0)
    assert scene.objects[down.object_index[0]].name == "table_top"
    assert down.distance_m[0] == pytest.approx(0.05, abs=1e-5)
    # the window sits in the north wall's opening: nothing lies behind it (its back side faces out)
    window = scene.object("window")
    centre = window.vertices.mean(axis=0)
    behind = rc.cast(centre + [0, 0.0005, 0], np.array([[0.0, 1.0, 0.0]]), 0.0)
    assert not behind.hit[0]
    # clutter within 0.45 m of the object, all of it below the first orbit (25 cm above the object)
    small = [o for o in scene.objects if np.ptp(o.vertices, axis=0).max() < 0.5]
    near = [o for o in small if np.linalg.norm(o.vertices.mean(axis=0)[:2] - scene.virtual_object_position[:2]) < 0.45]
    assert len(near) >= 5
    assert max(o.vertices[:, 2].max() for o in near) < scene.virtual_object_position[2] + 0.2


def trimesh_area(obj) -> float:
    t = obj.vertices[obj.faces]
    return float(0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum())


def test_mesh_objects_resolve_paths_against_the_scene_file(tmp_path):
    import trimesh

    (tmp_path / "m").mkdir()
    trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]],
                    face_colors=[[128, 128, 128, 255]], process=False).export(tmp_path / "m" / "t.ply")
    (tmp_path / "s.yaml").write_text("objects:\n  - {name: t, shape: mesh, file: m/t.ply}\n")
    (o,) = load_scene(tmp_path / "s.yaml").objects
    assert o.name == "t" and o.lit and len(o.faces) == 1
    with pytest.raises(InvalidInputError, match="object t: file: no such file"):
        scene_from_dict({"objects": [{"name": "t", "shape": "mesh", "file": "m/t.ply"}]}, base_dir=tmp_path / "elsewhere")

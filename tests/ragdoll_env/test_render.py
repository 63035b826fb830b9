"""The headless renderer: frame format, what lands where on screen, robustness."""

import sys
import warnings

import numpy as np
import pytest

from engine import math3d
from engine.builder import SceneBuilder
from engine.shapes import BOX, CAPSULE, NONE, PLANE, SPHERE, Sphere
from ragdoll_env.render import Camera, HumanViewer, Renderer, frame_strip, save_png

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
RED, GREEN, BLUE = (0.9, 0.1, 0.1), (0.1, 0.8, 0.1), (0.1, 0.2, 0.9)


def scene(*bodies, width=160, height=120, ground=True):
    """A renderer and pose for (type, params, position, orientation, colour) bodies above a ground plane."""
    if ground:
        bodies = ((PLANE, (0, 0, 0), (0, 0, 0), IDENTITY, (0.7, 0.7, 0.7)),) + bodies
    types = [b[0] for b in bodies]
    params = np.array([b[1] for b in bodies], dtype=float).reshape(-1, 3)
    pos = np.array([b[2] for b in bodies], dtype=float).reshape(-1, 3)
    quat = np.array([b[3] for b in bodies], dtype=float).reshape(-1, 4)
    colors = np.array([b[4] for b in bodies], dtype=float).reshape(-1, 3)
    return Renderer(types, params, width=width, height=height, colors=colors), pos, quat


def pixel(renderer, frame, point, target):
    col, row = renderer.project(np.asarray(point, dtype=float), target)
    return frame[int(row), int(col)].astype(int)


def is_color(rgb, dominant):
    """Whether channel ``dominant`` clearly outweighs the other two."""
    rgb = [int(c) for c in rgb]
    others = [c for k, c in enumerate(rgb) if k != dominant]
    return rgb[dominant] > max(others) + 40


@pytest.fixture(autouse=True)
def warnings_are_errors():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield


def test_default_frame_is_480_by_640_rgb_uint8():
    r, pos, quat = scene((SPHERE, (0.3, 0, 0), (0, 0, 1), IDENTITY, RED))
    r = Renderer(r.shape_type, r.shape_params)
    frame = r.render(pos, quat)
    assert frame.shape == (480, 640, 3) and frame.dtype == np.uint8
    assert frame.flags.c_contiguous


@pytest.mark.parametrize("size", [(64, 48), (101, 37), (200, 300)])
def test_custom_sizes(size):
    r, pos, quat = scene((SPHERE, (0.3, 0, 0), (0, 0, 1), IDENTITY, RED), width=size[0], height=size[1])
    assert r.render(pos, quat).shape == (size[1], size[0], 3)
    r.supersample = 2
    assert r.render(pos, quat).shape == (size[1], size[0], 3)


def test_sphere_in_front_of_camera_fills_the_centre_with_its_colour():
    r, pos, quat = scene((SPHERE, (0.3, 0, 0), (0, 0, 1), IDENTITY, RED))
    frame = r.render(pos, quat)
    h, w = frame.shape[:2]
    assert is_color(frame[h // 2, w // 2], 0)
    sky, ground = frame[0, 0].astype(int), frame[-1, 0].astype(int)
    assert sky[2] > sky[0], "top corner should be bluish sky"
    assert not is_color(ground, 0) and abs(ground[0] - ground[2]) < 40, "bottom corner should be grey ground"


def test_camera_is_upright_and_not_mirrored():
    target = np.array([0.0, 0.0, 1.0])
    r, pos, quat = scene((SPHERE, (0.15, 0, 0), (0, 0, 1.6), IDENTITY, RED),
                         (SPHERE, (0.15, 0, 0), (0, 0, 1), IDENTITY, GREEN))
    r.camera = Camera(azimuth_deg=-90.0, elevation_deg=0.0, distance=3.0)
    frame = r.render(pos, quat, target=target)
    rows = np.nonzero([is_color(px, 0) for px in frame[:, 80]])[0]
    assert rows.size and rows.mean() < 60, "an object above the target is in the upper half"
    # Looking along +y, world +x is to the right of the screen.
    pos[1] = (0.8, 0.0, 1.0)
    frame = r.render(pos, quat, target=target)
    cols = np.nonzero([is_color(px, 0) for px in frame[60]])[0]
    assert cols.size and cols.mean() > 80


def test_empty_scenes_render():
    r, pos, quat = scene()
    frame = r.render(pos, quat)
    assert frame.shape == (120, 160, 3)
    assert frame[0].std(axis=0).max() < 2.0, "sky row is uniform"
    nothing = Renderer(np.zeros(0, dtype=int), np.zeros((0, 3)), width=32, height=24)
    assert nothing.render(np.zeros((0, 3)), np.zeros((0, 4))).shape == (24, 32, 3)
    only_none = Renderer([NONE], [[0, 0, 0]], width=32, height=24)
    assert only_none.render(np.zeros((1, 3)), IDENTITY[None]).shape == (24, 32, 3)


def test_box_and_capsule_render_where_they_are():
    tilt = math3d.quat_from_axis_angle([1.0, 0.0, 0.0], 0.7)
    turn = math3d.quat_from_axis_angle([0.0, 0.0, 1.0], 0.5)
    r, pos, quat = scene((BOX, (0.2, 0.3, 0.15), (0, -0.6, 0.15), turn, GREEN),
                         (CAPSULE, (0.1, 0.3, 0), (0, 0.6, 0.6), tilt, BLUE))
    target = pos[1:].mean(axis=0)
    frame = r.render(pos, quat)
    assert is_color(pixel(r, frame, pos[1] + (0, 0, 0.15), target), 1)
    assert is_color(pixel(r, frame, pos[2], target), 2)
    ends = pos[2] + np.array([-1.0, 1.0])[:, None] * math3d.quat_rotate(tilt, np.array([0, 0, 0.3]))
    for end in ends:
        assert is_color(pixel(r, frame, end, target), 2), "capsule spans its whole segment"


def test_sloped_ground_and_supersampling():
    slope = math3d.quat_from_axis_angle([1.0, 0.0, 0.0], 0.3)
    r, pos, quat = scene((SPHERE, (0.2, 0, 0), (0, 0, 0.5), IDENTITY, RED))
    quat[0] = slope
    frame = r.render(pos, quat)
    r.supersample = 3
    smooth = r.render(pos, quat)
    assert np.abs(frame.astype(int) - smooth.astype(int)).mean() < 8
    h, w = frame.shape[:2]
    assert is_color(smooth[h // 2, w // 2], 0)


def test_pose_change_changes_the_image_and_same_input_gives_same_output():
    r, pos, quat = scene((SPHERE, (0.2, 0, 0), (0, 0, 0.5), IDENTITY, RED),
                         (CAPSULE, (0.1, 0.3, 0), (0.3, 0.4, 0.6), IDENTITY, BLUE))
    target = np.array([0.0, 0.0, 0.5])
    a = r.render(pos, quat, target=target)
    assert np.array_equal(a, r.render(pos.copy(), quat.copy(), target=target))
    assert np.array_equal(a, Renderer(r.shape_type, r.shape_params, 160, 120, r.colors).render(pos, quat, target))
    moved = pos.copy()
    moved[2, 0] += 0.2
    assert not np.array_equal(a, r.render(moved, quat, target=target))
    turned = quat.copy()
    turned[2] = math3d.quat_from_axis_angle([1.0, 0.0, 0.0], 1.0)
    assert not np.array_equal(a, r.render(pos, turned, target=target))


def test_default_target_follows_the_bodies():
    r, pos, quat = scene((SPHERE, (0.3, 0, 0), (5.0, -3.0, 1.0), IDENTITY, RED))
    frame = r.render(pos, quat)
    assert is_color(frame[60, 80], 0)
    np.testing.assert_allclose(r.default_target(pos), pos[1])


def test_bodies_cast_shadows_on_the_ground():
    r, pos, quat = scene((SPHERE, (0.25, 0, 0), (0, 0, 1.0), IDENTITY, RED))
    r.style.direction = (0.0, 0.0, 1.0)
    r.camera = Camera(elevation_deg=30.0, distance=3.0)
    target = np.array([0.0, 0.0, 0.5])
    shadowed = r.render(pos, quat, target=target)
    far = pos.copy()
    far[1] = (-20.0, 20.0, 1.0)
    open_sky = r.render(far, quat, target=target)
    below = pixel(r, shadowed, (0, 0, 0), target)
    assert below.sum() < 0.7 * pixel(r, open_sky, (0, 0, 0), target).sum()
    aside = (1.2, 0.0, 0.0)
    assert np.abs(pixel(r, shadowed, aside, target) - pixel(r, open_sky, aside, target)).max() <= 1


def test_no_warnings_or_garbage_in_hard_views():
    turn = math3d.quat_from_axis_angle([0.0, 0.0, 1.0], 0.3)
    r, pos, quat = scene((SPHERE, (0.3, 0, 0), (0, 0, 0.5), IDENTITY, RED),
                         (CAPSULE, (0.1, 0.4, 0), (0.5, 0, 0.5), IDENTITY, BLUE),
                         (BOX, (0.2, 0.2, 0.2), (-0.5, 0, 0.2), IDENTITY, GREEN),
                         (BOX, (0.2, 0.1, 0.3), (0.0, 0.8, 0.3), turn, GREEN))
    views = [
        dict(target=pos[1], camera=Camera(distance=0.1)),                     # eye inside the sphere
        dict(target=pos[3], camera=Camera(distance=0.05, azimuth_deg=0.0)),    # eye inside a box
        dict(target=pos[2], camera=Camera(distance=0.6, elevation_deg=0.0)),   # bodies behind and beside the eye
        dict(target=None, camera=Camera(elevation_deg=89.9)),                  # straight down
        dict(target=None, camera=Camera(elevation_deg=-30.0, distance=3.0)),   # from below the ground
        dict(target=None, camera=Camera(azimuth_deg=0.0, elevation_deg=0.0)),  # axis-aligned rays
        dict(target=np.array([0.0, 0.0, 1e-9]), camera=Camera(distance=1e-9, elevation_deg=0.0)),
    ]
    for kw in views:
        frame = r.render(pos, quat, **kw)
        assert frame.shape == (120, 160, 3)
    odd = Renderer(r.shape_type, r.shape_params, width=161, height=121)
    odd.style.direction = (0.0, 0.0, 1.0)
    assert odd.render(pos, quat, camera=Camera(azimuth_deg=0.0, elevation_deg=0.0)).shape == (121, 161, 3)
    broken = pos.copy()
    broken[2] = np.nan
    frame = r.render(broken, quat)
    assert frame.shape == (120, 160, 3)


def test_pose_with_a_world_axis_and_bad_shapes():
    r, pos, quat = scene((SPHERE, (0.3, 0, 0), (0, 0, 1), IDENTITY, RED))
    assert np.array_equal(r.render(pos[None], quat[None]), r.render(pos, quat))
    with pytest.raises(ValueError, match="2 bodies"):
        r.render(pos[:1], quat)
    with pytest.raises(ValueError, match="colors"):
        Renderer([SPHERE], [[0.1, 0, 0]], colors=[[1, 0, 0], [0, 1, 0]])


def test_from_model():
    b = SceneBuilder()
    b.add_ground()
    b.add_body("ball", Sphere(0.3), mass=1.0, position=(0, 0, 1))
    model = b.build()
    state = model.initial_state(1)
    r = Renderer.from_model(model, width=80, height=60)
    frame = r.render(state.position[0], state.orientation[0])
    assert frame.shape == (60, 80, 3)
    assert frame[30, 40, 0] > frame[30, 40, 2] + 40, "the first palette colour is a warm red"


def test_save_png_and_frame_strip(tmp_path):
    Image = pytest.importorskip("PIL.Image")
    r, pos, quat = scene((SPHERE, (0.3, 0, 0), (0, 0, 1), IDENTITY, RED), width=40, height=30)
    frames = [r.render(pos + (0.1 * k, 0, 0), quat) for k in range(3)]
    path = save_png(frames[0], tmp_path / "one.png")
    assert np.array_equal(np.asarray(Image.open(path)), frames[0])
    grid = frame_strip(frames, tmp_path / "grid.png", columns=2, gap=2)
    assert grid.shape == (62, 82, 3)
    assert np.array_equal(np.asarray(Image.open(tmp_path / "grid.png")), grid)
    assert np.array_equal(grid[32:62, 0:40], frames[2])
    assert frame_strip(frames, tmp_path / "row.png", gap=0).shape == (30, 120, 3)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="display detection by env vars is Linux-only")
def test_human_viewer_without_display_raises(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(RuntimeError, match="display"):
        HumanViewer()


def test_human_viewer_shows_frames_through_pygame(monkeypatch):
    import types

    shown = []
    fake = types.SimpleNamespace(QUIT=256)
    fake.display = types.SimpleNamespace(
        init=lambda: None, set_mode=lambda size: ("window", size), set_caption=lambda title: None,
        flip=lambda: None, quit=lambda: shown.append("quit"))
    fake.event = types.SimpleNamespace(get=lambda: [])
    fake.surfarray = types.SimpleNamespace(blit_array=lambda surface, array: shown.append((surface, array.shape)))
    monkeypatch.setitem(sys.modules, "pygame", fake)
    monkeypatch.setenv("DISPLAY", ":0")
    viewer = HumanViewer()
    viewer.show(np.zeros((30, 40, 3), dtype=np.uint8))
    viewer.close()
    viewer.show(np.zeros((30, 40, 3), dtype=np.uint8))
    assert shown == [(("window", (40, 30)), (40, 30, 3)), "quit"]

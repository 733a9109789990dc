"""Frames drawn by the Warp rasteriser (aquarium_warp.render), MP4 writing (aquarium_warp.video) and
the `video` CLI command. Agents are placed with `set_state` at pixel centres of a 1:1 frame, so world
point (x, y) is pixel [row y, column x]."""

import numpy as np
import pytest
import torch

from aquarium_warp import AquariumConfig, BatchedAquarium
from aquarium_warp.render import DEFAULT_PALETTE, Renderer, frame_size, render_world

BACKGROUND = np.array(DEFAULT_PALETTE["background"], np.uint8)
PREY_BODY = np.array(DEFAULT_PALETTE["prey_body"], np.uint8)
PREDATOR_BODY = np.array(DEFAULT_PALETTE["predator_body"], np.uint8)


def is_background(frame, x, y):
    return bool((frame[y, x] == BACKGROUND).all())


def place(env, agents, world=0):
    """Put agents (slot, x, y, heading angle in degrees clockwise from +x, speed) into `world`;
    every other slot is dead. Returns the env."""
    C = env.capacity
    position = torch.full((C, 2), 5.0)
    heading = torch.tensor([[1.0, 0.0]]).repeat(C, 1)
    velocity = torch.zeros(C, 2)
    alive = torch.zeros(C, dtype=torch.bool)
    for slot, x, y, angle, speed in agents:
        a = np.radians(angle)
        h = torch.tensor(np.round([np.cos(a), np.sin(a)], 12), dtype=torch.float32)  # exact axes
        position[slot] = torch.tensor([x, y])
        heading[slot] = h
        velocity[slot] = h * speed
        alive[slot] = True
    env.set_state(world=world, position=position, heading=heading, velocity=velocity, alive=alive)
    return env


@pytest.fixture
def env(device):
    """A 400 x 300 world with 2 prey slots (0, 1) and 1 predator slot (2), all dead until placed."""
    env = BatchedAquarium(
        AquariumConfig(width=400, height=300, prey_count=2, predator_count=1), num_worlds=1, device=device, seed=0
    )
    return place(env, [])


def test_frame_shape_dtype_and_size_rules(env):
    frame = render_world(env)
    assert frame.shape == (300, 400, 3) and frame.dtype == np.uint8
    assert render_world(env, width_px=200).shape == (150, 200, 3)
    assert render_world(env, height_px=60).shape == (60, 80, 3)
    assert render_world(env, width_px=64, height_px=32).shape == (32, 64, 3)
    assert frame_size(AquariumConfig(width=4000, height=1000)) == (1024, 256)  # long side capped at 1024
    with pytest.raises(ValueError):
        render_world(env, world=1)
    with pytest.raises(ValueError):
        render_world(env, width_px=0)


def test_background_where_no_agent(env):
    frame = render_world(env)
    assert (frame == BACKGROUND).all()  # every slot is dead
    place(env, [(0, 100.5, 100.5, 0, 0)])
    frame = render_world(env)
    assert is_background(frame, 300, 200) and is_background(frame, 0, 0) and is_background(frame, 100, 160)


def test_agent_pixels_where_it_is(env):
    place(env, [(0, 100.5, 100.5, 0, 0), (2, 250.5, 150.5, 0, 0)])
    frame = render_world(env)
    assert (frame[100, 100] == PREY_BODY).all()
    assert (frame[100, 95:106] != BACKGROUND).any(axis=1).all()  # along the body
    assert (frame[150, 262] == PREDATOR_BODY).all()  # ahead of the dark dorsal fin
    assert not (PREY_BODY == PREDATOR_BODY).all()
    assert is_background(frame, 100, 60) and is_background(frame, 160, 100)  # beyond the radius (20)
    assert is_background(frame, 250, 100) and is_background(frame, 320, 150)  # predator radius 30
    # the drawn pixels stay inside the hit boxes
    ys, xs = np.nonzero((frame != BACKGROUND).any(axis=2))
    near_prey = np.hypot(xs + 0.5 - 100.5, ys + 0.5 - 100.5) <= 21
    near_predator = np.hypot(xs + 0.5 - 250.5, ys + 0.5 - 150.5) <= 31
    assert (near_prey | near_predator).all()


def test_agent_across_the_seam(env):
    # a prey pointing up at x = 2: its body (half width 6 px) reaches over the left edge
    place(env, [(0, 2.5, 100.5, -90, 0)])
    frame = render_world(env)
    assert (frame[100, 2] == PREY_BODY).all()
    assert not is_background(frame, 398, 100) and not is_background(frame, 399, 100)
    # and one pointing right at x = 2: its tail is drawn at the right edge, its nose is not
    place(env, [(0, 2.5, 100.5, 0, 0)])
    frame = render_world(env)
    assert not (frame[95:106, 383:396] == BACKGROUND).all(axis=2).all()
    # across the bottom/top seam too
    place(env, [(0, 200.5, 298.5, 0, 0)])
    frame = render_world(env)
    assert not (frame[0:3, 195:205] == BACKGROUND).all()


def test_heading_orients_the_shape(env):
    place(env, [(0, 100.5, 100.5, 0, 0)])  # pointing right (+x)
    right = render_world(env)
    place(env, [(0, 100.5, 100.5, 180, 0)])  # pointing left
    left = render_world(env)
    place(env, [(0, 100.5, 100.5, 90, 0)])  # pointing down (+y, screen convention)
    down = render_world(env)
    # the tail fin lies 0.6 to 0.95 radii (12 to 19 px) behind the centre, the nose ends 14 px ahead
    assert not is_background(right, 85, 100) and is_background(right, 116, 100)
    assert not is_background(left, 116, 100) and is_background(left, 85, 100)
    assert not is_background(down, 100, 85) and is_background(down, 100, 116)
    # a half turn mirrors the picture about the centre (pixel centres mirror onto pixel centres)
    assert (right[:, 0:201] == left[:, 200::-1]).all()


def test_dead_agents_are_not_drawn(env):
    place(env, [(0, 100.5, 100.5, 0, 0), (2, 250.5, 150.5, 0, 0)])
    place(env, [(2, 250.5, 150.5, 0, 0)])  # slot 0 dead, keeps its position
    frame = render_world(env)
    assert is_background(frame, 100, 100) and not is_background(frame, 250, 150)


def test_overlays_change_pixels(env):
    place(env, [(0, 100.5, 100.5, 0, 4.0), (2, 330.5, 250.5, 180, 5.0)])
    plain = render_world(env)
    cones = render_world(env, view_cones=True)
    boxes = render_world(env, hit_boxes=True)
    arrows = render_world(env, velocities=True)
    for frame in (cones, boxes, arrows):
        assert (frame != plain).any()
    # view cone (prey: 100 px, 120 degrees): tinted ahead, not behind or outside the angle
    assert not is_background(cones, 160, 100) and is_background(cones, 40, 100)
    assert is_background(cones, 100, 160)  # 90 degrees off the heading
    assert not is_background(cones, 150, 140)  # 39 degrees off, 63 px away
    # predator cone (200 px, 150 degrees, pointing left) reaches x = 150 but not behind it
    assert not is_background(cones, 150, 250) and is_background(cones, 380, 250)
    assert not (cones[100, 160] == cones[250, 150]).all()  # the two types' cones differ in colour
    # hit box: a ring at the radius beside the agent, where the plain frame is background
    assert is_background(plain, 100, 120) and (boxes[120, 100] == DEFAULT_PALETTE["prey_hit_box"]).all()
    assert (boxes[250, 300] == DEFAULT_PALETTE["predator_hit_box"]).all()
    assert is_background(boxes, 100, 130)
    # velocity arrow: 10 steps of (4, 0) from the prey, beyond its nose
    assert (arrows[100, 130] == DEFAULT_PALETTE["velocity"]).all() and is_background(arrows, 145, 100)
    assert (arrows[250, 290] == DEFAULT_PALETTE["velocity"]).all()  # predator moving left at 5
    # overlays together, and deterministic
    both = render_world(env, view_cones=True, hit_boxes=True, velocities=True)
    assert (both == render_world(env, view_cones=True, hit_boxes=True, velocities=True)).all()


def test_view_cone_without_fov_is_a_disc(device):
    cfg = AquariumConfig(width=400, height=300, prey_count=1, predator_count=1, fov_enabled=False)
    env = place(BatchedAquarium(cfg, num_worlds=1, device=device, seed=0), [(0, 100.5, 100.5, 0, 0)])
    cones = render_world(env, view_cones=True)
    assert not is_background(cones, 40, 100) and not is_background(cones, 100, 160)  # behind, beside
    assert is_background(cones, 100, 210)  # beyond the view distance (100)


def test_cached_renderer_does_not_keep_the_env_alive(device):
    import gc
    import weakref

    env = BatchedAquarium(AquariumConfig(), num_worlds=1, device=device, seed=0)
    render_world(env, width_px=32)
    ref = weakref.ref(env)
    del env
    gc.collect()
    assert ref() is None


def test_window_shows_frames(env):
    pytest.importorskip("pygame")
    from aquarium_warp.render import Window

    renderer = Renderer(env, width_px=100)
    window = Window(renderer.width_px, renderer.height_px, fps=None)  # SDL's dummy driver (conftest)
    try:
        assert window.show(renderer.render())
    finally:
        window.close()
    assert not window.show(renderer.render())


def test_renders_any_world_of_a_batch(device):
    env = BatchedAquarium(AquariumConfig(), num_worlds=4, device=device, seed=3)
    renderer = Renderer(env, width_px=200)
    frames = [renderer.render(w) for w in range(4)]
    assert (frames[3] != frames[0]).any()
    # the renderer's frames are copies: rendering another world does not change an earlier frame
    assert (frames[0] == renderer.render(0)).all()
    # a world's own picture: world 3 drawn alone equals world 3 drawn in the batch
    single = BatchedAquarium(AquariumConfig(), num_worlds=1, device=device, seed=3)
    state = {k: getattr(env.state.torch, k)[3].cpu() for k in ("position", "heading", "velocity", "alive")}
    single.set_state(world=0, **state)
    assert (Renderer(single, width_px=200).render(0) == frames[3]).all()


def test_tiny_agents_are_dots(device):
    # 50 px per image pixel: a prey (radius 20) is one pixel at its centre
    cfg = AquariumConfig(width=10000, height=10000, prey_count=300, predator_count=1)
    env = BatchedAquarium(cfg, num_worlds=1, device=device, seed=1)
    frame = render_world(env, width_px=200)
    drawn = (frame != BACKGROUND).any(axis=2)
    pos = env.state.torch.position[0].cpu().numpy()
    inv = np.float32(1.0) / np.float32(50.0)  # the kernel's float32 arithmetic
    cols, rows = (pos[:, 0] * inv).astype(int), (pos[:, 1] * inv).astype(int)
    assert drawn[rows, cols].all()
    assert drawn.sum() == len(set(zip(rows.tolist(), cols.tolist())))


def test_write_video_reads_back(tmp_path):
    imageio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    from aquarium_warp.video import write_video

    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 255, (49, 65, 3), dtype=np.uint8) for _ in range(5)]  # odd sizes get padded
    path = tmp_path / "noise.mp4"
    assert write_video(frames, path, fps=10, progress=False) == 5
    reader = imageio.get_reader(str(path))
    read = list(reader.iter_data())  # not list(reader): its len() is sys.maxsize while the length is unknown
    assert len(read) == 5 and read[0].shape == (50, 66, 3)
    assert write_video(lambda i: frames[i] if i < 3 else None, tmp_path / "c.mp4", num_frames=5, progress=False) == 3
    with pytest.raises(ValueError):
        write_video([frames[0], frames[0][:10]], tmp_path / "bad.mp4", progress=False)


def test_write_video_takes_an_x264_preset_and_refuses_others(tmp_path):
    imageio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    from aquarium_warp.video import write_video

    frames = [np.full((32, 48, 3), 40 * i, dtype=np.uint8) for i in range(4)]
    assert write_video(frames, tmp_path / "fast.mp4", fps=10, progress=False, preset="ultrafast") == 4
    read = list(imageio.get_reader(str(tmp_path / "fast.mp4")).iter_data())
    assert len(read) == 4 and abs(int(read[3].mean()) - 120) <= 3  # the last frame's grey, through yuv420p
    with pytest.raises(ValueError, match=r"preset='quick' must be None or one of \['ultrafast'"):
        write_video(frames, tmp_path / "bad.mp4", progress=False, preset="quick")
    assert not (tmp_path / "bad.mp4").exists()


def test_record_and_cli_video(device, tmp_path):
    imageio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    from aquarium_warp.cli import main
    from aquarium_warp.video import record

    env = BatchedAquarium(AquariumConfig(), num_worlds=2, device=device, seed=0)
    zeros = {
        "prey": torch.zeros(2, env.prey_capacity, dtype=torch.int64, device=env.torch_device),
        "predator": torch.zeros(2, env.predator_capacity, dtype=torch.int64, device=env.torch_device),
    }
    path = tmp_path / "record.mp4"
    assert record(env, lambda obs: zeros, 4, path, world=1, width_px=128, progress=False, view_cones=True) == 5
    reader = imageio.get_reader(str(path))
    assert reader.count_frames() == 5 and reader.get_data(0).shape == (128, 128, 3)

    out = tmp_path / "cli.mp4"
    assert (
        main(
            [
                "video",
                "--steps",
                "3",
                "--out",
                str(out),
                "--device",
                device,
                "--frame-width",
                "96",
                "--prey",
                "5",
                "--hit-boxes",
                "--velocities",
                "--no-progress",
            ]
        )
        == 0
    )
    assert imageio.get_reader(str(out)).count_frames() == 4
    vortex = tmp_path / "vortex.mp4"
    assert (
        main(
            [
                "video",
                "--steps",
                "2",
                "--out",
                str(vortex),
                "--device",
                device,
                "--frame-width",
                "96",
                "--flow",
                "vortex",
                "--draw-flow",
                "--no-progress",
            ]
        )
        == 0
    )
    assert imageio.get_reader(str(vortex)).count_frames() == 3


def test_flow_arrows_where_the_current_is_not_zero(device):
    """`draw_flow=True` on a 600 x 600 world framed 1:1, grid current of 4 cells across, (0, 0), (0, 0),
    (4, 0), (4, 0) px/step: the current is zero for x in [75, 225] (between the first two cell
    centres) and not zero from 225 to 600 + 75. Arrows (32 px apart, at most 0.9 x 32 px long, along
    +x) mark pixels in the second region, none in [105, 225) (the arrows from left of 75 end before);
    the frame keeps its shape, and the world with no flow is drawn as without the option."""
    from aquarium_warp.config import FlowConfig

    grid = [[[0.0, 0.0], [0.0, 0.0], [4.0, 0.0], [4.0, 0.0]]]
    cfg = AquariumConfig(
        width=600, height=600, prey_count=2, predator_count=1, flow=(FlowConfig("grid", grid=grid), FlowConfig())
    )
    env = BatchedAquarium(cfg, num_worlds=2, device=device, seed=0)
    for w in range(2):
        place(env, [], world=w)
    renderer = Renderer(env, 600, 600)
    plain, flow = renderer.render(0), renderer.render(0, draw_flow=True)
    assert flow.shape == plain.shape == (600, 600, 3) and flow.dtype == np.uint8
    arrows = (flow != plain).any(axis=2)
    assert (flow[arrows] == np.array(DEFAULT_PALETTE["flow"], np.uint8)).all()
    assert not arrows[:, 105:225].any()
    assert arrows[:, 240:600].sum() > 100
    assert np.array_equal(renderer.render(1, draw_flow=True), renderer.render(1))
    with pytest.raises(ValueError, match="flow_spacing"):
        Renderer(env, flow_spacing=2)

"""`aquarium-warp view` (aquarium_warp/viewer): page messages, the simulation behind the page, the
server over a real socket, recordings and replay pages, and the page itself in a real browser (the
system's chromium through Selenium; CI installs it, elsewhere those tests skip)."""

import contextlib
import json
import logging
import os
import shutil
import socket
import threading
import time

import numpy as np
import pytest

pytest.importorskip("starlette", reason="the viewer extra: pip install 'aquarium-warp[viewer]'")
uvicorn = pytest.importorskip("uvicorn", reason="the viewer extra: pip install 'aquarium-warp[viewer]'")
from websockets.sync.client import connect  # noqa: E402 - after the extra's check

from aquarium_warp.cli import main  # noqa: E402
from aquarium_warp.viewer.messages import MessageError, parse_message  # noqa: E402
from aquarium_warp.viewer.recording import read_trajectory, replay_page  # noqa: E402
from aquarium_warp.viewer.server import (  # noqa: E402
    Viewer,
    pack_frame,
    select_agents,
    server_config,
    unpack_frame,
)
from aquarium_warp.viewer.simulation import Simulation, ViewOptions  # noqa: E402

BAD_MESSAGES = [
    (b"\x00binary", "binary"),
    ("not json", "not JSON"),
    ("[1, 2]", "JSON object"),
    ('{"type": "explode"}', "type="),
    ('{"type": "play", "extra": 1}', "unknown fields ['extra']"),
    ('{"type": "speed"}', "missing fields ['value']"),
    ('{"type": "speed", "value": 100}', "speed=100.0 must be in [0.1, 16.0]"),
    ('{"type": "speed", "value": "fast"}', "finite number"),
    ('{"type": "speed", "value": NaN}', "finite number"),
    ('{"type": "world", "index": 2}', "in [0, 1]"),
    ('{"type": "world", "index": true}', "in [0, 1]"),
    ('{"type": "world", "index": -1}', "in [0, 1]"),
    ('{"type": "overlays", "view_cones": 1, "hit_boxes": false, "velocities": false, "flow": false}', "true or false"),
    ('{"type": "view", "rect": [0, 0, 10]}', "[x0, y0, x1, y1]"),
    ('{"type": "view", "rect": [5, 0, 1, 10]}', "x0 < x1"),
    ('{"type": "policy", "team": "fish", "spec": "random"}', "team="),
    ('{"type": "policy", "team": "prey", "spec": ""}', "non-empty string"),
    ('{"type": "policy", "team": "prey", "spec": 3}', "non-empty string"),
    ('{"type": "policy", "team": "prey", "spec": "' + "x" * 2000 + '"}', "non-empty string"),
    ('{"type": "human", "team": ["prey"]}', "team="),
    ('{"type": "keys", "dx": 2, "dy": 0}', "dx=2 must be -1, 0 or 1"),
    ('{"type": "keys", "dx": 1.0, "dy": 0}', "dx=1.0"),
    ('{"type": "record", "on": "yes"}', "true or false"),
    ('{"type": "inspect", "slot": 17}', "slot=17 must be an integer in [0, 16]"),
    ('{"type": "inspect", "slot": true}', "slot=True must be an integer in [0, 16]"),
    ('{"type": "move", "slot": -1, "x": 0, "y": 0}', "slot=-1 must be an integer in [0, 16]"),
    ('{"type": "move", "slot": 0, "x": "left", "y": 0}', "x='left' must be a finite number"),
    ('{"type": "move", "slot": 0, "x": 1}', "missing fields ['y']"),
    ("[" * 100000, "characters"),
]


@pytest.mark.parametrize(("text", "says"), BAD_MESSAGES)
def test_bad_messages_are_refused_with_a_reason(text, says):
    with pytest.raises(MessageError, match=None) as error:
        parse_message(text, num_worlds=2, capacity=17)
    assert says in str(error.value)


def test_good_messages_are_checked_and_kept():
    assert parse_message('{"type": "keys", "dx": -1, "dy": 1}', 1, 17) == {"type": "keys", "dx": -1, "dy": 1}
    assert parse_message('{"type": "view", "rect": [0, 0, 1.5, 2]}', 1, 17)["rect"] == (0.0, 0.0, 1.5, 2.0)
    assert parse_message('{"type": "policy", "team": "prey", "spec": " prey-a "}', 1, 17)["spec"] == "prey-a"
    assert parse_message('{"type": "human", "team": null}', 1, 17)["team"] is None
    assert parse_message('{"type": "inspect", "slot": 16}', 1, 17) == {"type": "inspect", "slot": 16}
    assert parse_message('{"type": "inspect", "slot": null}', 1, 17)["slot"] is None
    move = parse_message('{"type": "move", "slot": 3, "x": 1, "y": 2.5}', 1, 17)
    assert move == {"type": "move", "slot": 3, "x": 1.0, "y": 2.5}


@pytest.fixture
def simulation(tmp_path):
    return Simulation(ViewOptions(worlds=2, device="cpu", policy_dir=str(tmp_path)))


@pytest.mark.slow  # loading a junk file through the policy loaders takes seconds
def test_only_heuristics_shipped_names_and_allowed_files_may_be_chosen(simulation, tmp_path):
    assert simulation.allowed_spec("prey", "TurnAway") == "TurnAway"
    assert simulation.allowed_spec("prey", "PREY-A") == "prey-a"
    assert simulation.allowed_spec("predator", "naivchase-noconfusion") == "naivchase-noconfusion"
    with pytest.raises(ValueError, match="not allowed"):
        simulation.allowed_spec("prey", "/etc/passwd")
    with pytest.raises(ValueError, match="not allowed"):  # a way out of the folder is still outside it
        simulation.allowed_spec("prey", str(tmp_path / ".." / "x.pt"))
    with pytest.raises(ValueError, match="does not exist"):
        simulation.allowed_spec("prey", str(tmp_path / "missing.pt"))
    with pytest.raises(ValueError, match="not allowed"):
        simulation.allowed_spec("prey", "naivchase")  # a predator's heuristic
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a policy")
    assert simulation.allowed_spec("prey", str(junk)) == os.path.realpath(junk)
    with pytest.raises(ValueError, match="cannot run"):  # allowed, but no policy: the old teams stay
        simulation.set_policy("prey", str(junk))
    assert simulation.specs["prey"] == "turnaway"
    assert str(junk) in " ".join(simulation.policy_choices()["prey"])


def test_a_shipped_policy_switches_the_world_without_a_new_simulation(simulation):
    simulation.set_policy("prey", "prey-a")
    assert simulation.specs["prey"] == "prey-a"
    assert simulation.env.config.prey_count == 6  # prey-a's world
    simulation.advance()
    simulation.set_policy("prey", "random")
    assert simulation.env.config.prey_count == 16


@pytest.mark.parametrize(("dx", "dy"), [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1)])
def test_keys_steer_the_human_agent(simulation, dx, dy):
    simulation.apply({"type": "world", "index": 1})
    simulation.apply({"type": "human", "team": "predator"})
    simulation.apply({"type": "keys", "dx": dx, "dy": dy})
    slot = simulation.human_agent()
    start = simulation.env.state.torch.position[1, slot].clone()
    for _ in range(40):
        simulation.step()
    moved = (simulation.env.state.torch.position[1, slot] - start).numpy()
    moved = (moved + 400.0) % 800.0 - 400.0  # the torus' shortest displacement (the world is 800 x 800)
    want = np.array([dx, dy], dtype=np.float32) / np.hypot(dx, dy)
    # 40 steps at up to 5 px/step: well over 60 px along the keys' direction
    assert float(moved @ want) > 60.0


def test_select_agents_thins_prey_and_keeps_predators_and_the_human():
    n, prey = 1000, 990
    rng = np.random.default_rng(0)
    snapshot = {
        "alive": np.ones(n, bool),
        "position": rng.uniform(0, 100, (n, 2)).astype(np.float32),
        "header": {"prey_capacity": prey, "width": 100.0, "height": 100.0},
    }
    slots = select_agents(snapshot, None, 100, human=5)
    assert len(slots) <= 101 and set(range(prey, n)) <= set(slots.tolist()) and 5 in slots
    inside = select_agents(snapshot, (0, 0, 50, 50), 10**6, human=None)
    p = snapshot["position"][inside]
    assert len(inside) > 100 and (p <= 50).all()
    # a view reaching past the seam (x < 0, y > 100) also gets the agents across it
    across = select_agents(snapshot, (-10, 60, 30, 110), 10**6, human=None)
    x, y = snapshot["position"].T
    want = ((x <= 30) | (x >= 90)) & ((y >= 60) | (y <= 10))
    assert sorted(across.tolist()) == np.flatnonzero(want).tolist()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def serve(viewer, port=None):
    """The viewer's app on uvicorn on `port` (default: a free one), on a thread; yields the port."""
    port = port or _free_port()
    server = uvicorn.Server(server_config(viewer, host="127.0.0.1", port=port))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.time() + 30
    while not server.started:
        assert time.time() < deadline and thread.is_alive(), "the viewer did not start"
        time.sleep(0.05)
    try:
        yield port
    finally:
        server.should_exit = True
        thread.join(30)


def _next_frame(ws) -> dict:
    while True:
        data = ws.recv(timeout=10)
        if isinstance(data, bytes):
            n = int(np.frombuffer(data[:4], "<u4")[0])
            return json.loads(data[4 : 4 + n])


@pytest.fixture(scope="module")
def server():
    viewer = Viewer(Simulation(ViewOptions(worlds=2, device="cpu")))
    with serve(viewer) as port:
        yield viewer, port


@pytest.mark.parametrize(
    ("text", "says"),
    [(t, s) for t, s in BAD_MESSAGES if isinstance(t, str)]
    + [('{"type": "policy", "team": "prey", "spec": "/etc/passwd"}', "not allowed")],
)
def test_the_server_answers_bad_messages_and_keeps_serving(server, text, says):
    viewer, port = server
    with connect(f"ws://127.0.0.1:{port}/ws", max_size=None) as ws:
        hello = json.loads(ws.recv(timeout=10))
        assert hello["type"] == "hello" and "prey-a" in hello["choices"]["prey"]
        ws.send(text)
        while True:
            reply = ws.recv(timeout=10)
            if isinstance(reply, str):
                break
        assert json.loads(reply)["type"] == "error" and says in json.loads(reply)["message"]
        before = _next_frame(ws)["step"]
        ws.send('{"type": "play"}')
        deadline = time.time() + 10
        while _next_frame(ws)["step"] == before:
            assert time.time() < deadline


def test_swarm_metrics_are_computed_once_per_state(monkeypatch):
    """A tick that computes the swarm metrics is a late frame: an unchanged state (paused) reuses them,
    a step, a drag or a reset gives a new state."""
    sim = Simulation(ViewOptions(device="cpu"))
    compute, calls = sim.view.metrics.compute, []
    monkeypatch.setattr(sim.view.metrics, "compute", lambda: calls.append(1) or compute())
    for _ in range(3):
        sim.snapshot()
        sim.view._due = 0.0  # and however old the result
    assert len(calls) == 1
    sim.apply({"type": "step"})
    assert sim.advance() == 1
    sim.snapshot()
    assert len(calls) == 2
    sim.apply({"type": "move", "slot": 0, "x": 10.0, "y": 10.0})
    sim.snapshot()
    sim.apply({"type": "reset"})
    sim.snapshot()
    assert len(calls) == 4


def test_frames_go_out_uncompressed(server):
    """The client offers per-message deflate (websockets' default); the server declines it: deflating a
    megabyte frame of 100,000 agents took about 70 ms, the send rate's limit."""
    with connect(f"ws://127.0.0.1:{server[1]}/ws", max_size=None) as ws:
        assert "permessage-deflate" in ws.request.headers["Sec-WebSocket-Extensions"]
        assert "Sec-WebSocket-Extensions" not in ws.response.headers
        assert isinstance(_next_frame(ws)["step"], int)


def test_frames_decode(server):
    snapshot = server[0].snapshot  # once: the server publishes a new one every frame
    header, agents = unpack_frame(pack_frame(snapshot, None, 1000, velocities=False))
    slots = agents["slots"]
    assert header["n"] == header["alive_total"] == 17 and sorted(slots) == list(range(17))
    # positions to half a step of 800 / 65536 px, headings to half a step of 2 pi / 65536
    off = (agents["position"] - snapshot["position"][slots] + 400.0) % 800.0 - 400.0  # on the torus
    assert np.abs(off).max() <= 800 / 131072
    np.testing.assert_allclose(agents["heading"], snapshot["heading"][slots], rtol=0, atol=np.pi / 65536 + 1e-6)
    assert agents["velocity"] is None and agents["flow"] is None


def test_a_frame_is_ten_bytes_an_agent_in_quanta_of_the_world_and_the_circle():
    """Three agents of a 800 x 400 world, by hand: x = q / 65536 * 800, y = q / 65536 * 400, the
    heading's angle = q / 65536 * 2 pi; a position at the far edge wraps to 0 (the torus)."""
    snapshot = {
        "alive": np.array([True, True, False, True]),
        "position": np.array([[0.0, 0.0], [400.0, 100.0], [1.0, 1.0], [799.999, 200.00305]], np.float32),
        "heading": np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0], [0.0, -1.0]], np.float32),
        "velocity": np.array([[0.5, -2.0], [0.0, 0.0], [0.0, 0.0], [3.0, 0.25]], np.float32),
        "flow": np.arange(2 * 3 * 2, dtype=np.float32).reshape(2, 3, 2),
        "inspect": {},
        "header": {"width": 800.0, "height": 400.0, "prey_capacity": 2, "human": None},
    }
    frame = pack_frame(snapshot, None, 100, flow=True, velocities=True)
    length = int(np.frombuffer(frame, "<u4", 1)[0])
    body = frame[4 + length :]
    # slots, positions, angles (+ 2 bytes: n = 3 is odd), float16 velocities, float32 flow
    assert len(body) == 3 * 4 + 3 * 4 + 3 * 2 + 2 + 3 * 4 + 2 * 3 * 2 * 4
    assert np.frombuffer(body, "<u4", 3).tolist() == [0, 1, 3]
    assert np.frombuffer(body, "<u2", 6, 12).tolist() == [0, 0, 32768, 16384, 0, 32768]
    assert np.frombuffer(body, "<u2", 3, 24).tolist() == [0, 16384, 49152]
    header, agents = unpack_frame(frame)
    assert header["velocities"] and header["flow_shape"] == [2, 3]
    np.testing.assert_allclose(agents["position"], [[0, 0], [400, 100], [0, 200]])
    np.testing.assert_allclose(agents["heading"], [[1, 0], [0, 1], [0, -1]], atol=1e-12)
    np.testing.assert_array_equal(agents["velocity"], [[0.5, -2.0], [0.0, 0.0], [3.0, 0.25]])
    np.testing.assert_array_equal(agents["flow"], snapshot["flow"])
    without = pack_frame(snapshot, None, 100, flow=False, velocities=False)
    length = int(np.frombuffer(without, "<u4", 1)[0])
    assert len(without) - 4 - length == 3 * 4 + 3 * 4 + 3 * 2 + 2  # ten bytes an agent, and the padding
    header, agents = unpack_frame(without)
    assert not header["velocities"] and agents["velocity"] is None and agents["flow"] is None


@pytest.mark.slow
def test_record_writes_an_mp4_and_a_replay_page_plays_it(tmp_path):
    video = tmp_path / "run.mp4"
    viewer = Viewer(Simulation(ViewOptions(device="cpu")), record=str(video))
    with serve(viewer):
        deadline = time.time() + 30
        while viewer.frames < 20:
            assert time.time() < deadline
            time.sleep(0.05)
    assert video.stat().st_size > 1000
    imageio = pytest.importorskip("imageio.v2")
    assert imageio.get_reader(str(video)).get_data(0).shape == (768, 768, 3)  # the 800 px world at 768 px
    trajectory = read_trajectory(str(tmp_path / "run.json"))
    assert len(trajectory["frames"]) >= 19 and trajectory["meta"]["prey_capacity"] == 16
    assert main(["view", "--replay", str(tmp_path / "run.json"), "--out", str(tmp_path / "run.html")]) == 0
    page = (tmp_path / "run.html").read_text()
    assert 'id="replay-data"' in page and "static/viewer.js" not in page and "</script>" in replay_page(trajectory)


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--port", "70000"], "--port: invalid value '70000': must be an integer in [1, 65535]"),
        (["--worlds", "0"], "--worlds: invalid value '0': must be an integer in [1, 65536]"),
        (["--prey", "-3"], "--prey: invalid value '-3'"),
        (["--human", "shark"], "--human: invalid choice"),
        (["--fps", "500"], "--fps: invalid value '500': must be a number in [1, 120]"),
        (["--record-size", "10"], "--record-size: invalid value '10': must be an integer in [64, 4096]"),
        (["--record", "out.avi"], "must end in .mp4"),
        (["--replay", "nothing.json", "--out", "x.html"], "--replay nothing.json: cannot read"),
        (["--replay", "x.json"], "--replay FILE.json and --out PAGE.html go together"),
        (["--prey-policy", "/no/such/policy.pt"], "does not exist"),
    ],
)
def test_view_options_are_checked_in_one_line(argv, says, capsys):
    try:
        code = main(["view", *argv])
    except SystemExit as exit_:
        code = exit_.code
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and says in err


def test_a_port_in_use_is_refused_before_the_address_is_printed(capsys, monkeypatch):
    def no_world(*args, **kwargs):
        raise AssertionError("the world was built before the port was checked")

    monkeypatch.setattr("aquarium_warp.viewer.simulation.Simulation.__init__", no_world)
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        assert main(["view", "--port", str(port), "--device", "cpu"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""  # neither the world nor "open http://..."
    assert captured.err.strip() == (
        f"aquarium-warp view: --port {port}: cannot serve on 127.0.0.1:{port} (Address already in use)"
    )


def test_record_into_a_folder_that_cannot_take_it_is_refused_before_serving(tmp_path, capsys, monkeypatch):
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o500)
    path = str(folder / "run.mp4")
    if os.access(folder, os.W_OK):  # root writes anywhere the permissions say no; /sys refuses even root
        path = "/sys/run.mp4"
        if not os.path.isdir("/sys"):
            pytest.skip("neither a read-only folder nor /sys here")

    def no_server(*args, **kwargs):
        raise AssertionError("the viewer started serving")

    monkeypatch.setattr(uvicorn.Server, "run", no_server)
    assert main(["view", "--device", "cpu", "--record", path]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"aquarium-warp view: --record: cannot write {path}: "), err
    assert "denied" in err[0] or "Read-only" in err[0], err


def test_the_trajectory_is_written_atomically(tmp_path, monkeypatch):
    """A full disk while the trajectory is written leaves the previous file whole and no partial one."""
    import errno

    from aquarium_warp import atomic
    from aquarium_warp.viewer.recording import write_trajectory

    path = tmp_path / "run.json"
    write_trajectory(str(path), {"width": 1.0}, [{"t": 0}])
    previous = path.read_text()

    def no_space(name):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), name)

    monkeypatch.setattr(atomic, "_fsync", no_space)
    with pytest.raises(OSError, match="No space left"):
        write_trajectory(str(path), {"width": 2.0}, [{"t": 0}, {"t": 1}])
    assert path.read_text() == previous and os.listdir(tmp_path) == ["run.json"]


@pytest.mark.slow
@pytest.mark.parametrize(("signals", "code", "says"), [(2, 130, "interrupted"), (1, 143, "terminated (SIGTERM)")])
def test_one_or_two_signals_end_the_server_in_one_line_with_the_signals_code(signals, code, says):
    """A double Ctrl-C (or `timeout -s INT`) and SIGTERM: the viewer stops with the shell's code for the
    signal and one line, not uvicorn's and asyncio's tracebacks."""
    import signal
    import subprocess
    import sys

    signum = signal.SIGINT if code == 130 else signal.SIGTERM
    argv = [sys.executable, "-m", "aquarium_warp", "view", "--device", "cpu", "--port", str(_free_port())]
    proc = subprocess.Popen(
        argv,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # a shell's background jobs ignore it
    )
    try:
        assert "open http://" in proc.stdout.readline() + proc.stdout.readline()
        time.sleep(1.0)  # serving
        for _ in range(signals):
            proc.send_signal(signum)
            time.sleep(0.05)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == code and err.strip() == f"aquarium-warp view: {says}", err


# ---------------------------------------------------------------------- a real browser
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
browser_only = pytest.mark.skipif(
    CHROMIUM is None or CHROMEDRIVER is None,
    reason="needs the system chromium and chromedriver (apt-get install chromium "
    "chromium-driver; .ci/run installs them)",
)


@pytest.fixture(scope="module")
def browser_server():
    viewer = Viewer(Simulation(ViewOptions(worlds=3, device="cpu")))
    with serve(viewer) as port:
        yield viewer, f"http://127.0.0.1:{port}/"


def _browser(*flags: str):
    """Headless chromium (WebGL2 on SwiftShader, its software GPU, unless `flags` take it away)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    for argument in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1280,800", *flags):
        options.add_argument(argument)
    options.binary_location = CHROMIUM
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})  # the page's console, for get_log
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)


@pytest.fixture(scope="module")
def page(browser_server):
    driver = _browser()
    driver.get(browser_server[1])
    yield driver
    driver.quit()


def _until(predicate, timeout=15.0):
    deadline = time.time() + timeout
    while not predicate():
        assert time.time() < deadline, "timed out"
        time.sleep(0.05)


def _header(page):
    return page.execute_script("return window.aquarium.frame && window.aquarium.frame.header")


@browser_only
@pytest.mark.slow
def test_page_loads_and_frames_arrive_and_change(page):
    _until(lambda: page.execute_script("return window.aquarium.framesDrawn") > 5)
    first = page.execute_script("return Array.from(window.aquarium.frame.agents.slice(0, 2))")
    _until(lambda: page.execute_script("return Array.from(window.aquarium.frame.agents.slice(0, 2))") != first)
    assert page.find_element("id", "agents").text == "17 / 17"
    # WebGL2 is offered (SwiftShader), but 17 agents are drawn with Canvas 2D (?renderer=auto: from 2,000)
    assert page.execute_script("return [window.aquarium.renderer, window.aquarium.glName !== null]") == [
        "canvas2d",
        True,
    ]
    assert "turnaway" in page.find_element("id", "prey-choice").get_attribute("innerHTML")


@browser_only
@pytest.mark.slow
def test_play_pause_step_and_world_switching(page, browser_server):
    viewer = browser_server[0]
    _until(lambda: _header(page) is not None and _header(page)["playing"])
    page.find_element("id", "play").click()
    _until(lambda: not viewer.simulation.playing and not _header(page)["playing"])
    paused = viewer.simulation.env.state.torch.world_step[0].item()
    time.sleep(0.3)
    assert viewer.simulation.env.state.torch.world_step[0].item() == paused
    page.find_element("id", "step").click()
    _until(lambda: _header(page)["step"] == paused + 1)
    world = page.find_element("id", "world-index")
    world.clear()
    world.send_keys("2\n")
    _until(lambda: viewer.simulation.world == 2 and _header(page)["world"] == 2)
    page.find_element("id", "play").click()
    _until(lambda: viewer.simulation.playing)


@browser_only
@pytest.mark.slow
def test_a_key_press_moves_the_human_agent(page, browser_server):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys
    from selenium.webdriver.support.ui import Select

    viewer = browser_server[0]
    Select(page.find_element("id", "human")).select_by_value("predator")
    _until(lambda: viewer.simulation.human == "predator" and _header(page)["human"] is not None)
    sim = viewer.simulation
    slot, world = sim.human_agent(), sim.world
    for key, want in ((Keys.ARROW_RIGHT, (1.0, 0.0)), (Keys.ARROW_UP, (0.0, -1.0))):
        page.find_element("id", "world").click()
        ActionChains(page).key_down(key).perform()
        # the server's simulation state: the human's predator heads the way of the key
        _until(lambda want=want: float(sim.env.state.torch.heading[world, slot] @ _tensor(want)) > 0.95)
        ActionChains(page).key_up(key).perform()
    assert "predator" in page.find_element("id", "human-stats").text


def _tensor(values):
    import torch

    return torch.tensor(values)


@browser_only
@pytest.mark.slow
def test_a_bad_policy_path_shows_an_error_and_the_server_keeps_running(page, browser_server):
    viewer = browser_server[0]
    spec = page.find_element("id", "prey-spec")
    spec.clear()
    spec.send_keys("/etc/passwd")
    page.find_element("id", "prey-apply").click()
    _until(lambda: "not allowed" in page.find_element("id", "error").text)
    frames = viewer.frames
    _until(lambda: viewer.frames > frames + 5)
    step = _header(page)["step"]
    _until(lambda: _header(page)["step"] > step)


@browser_only
@pytest.mark.slow
def test_two_pages_at_once(page, browser_server):
    second = _browser()
    try:
        second.get(browser_server[1])
        _until(lambda: second.execute_script("return window.aquarium.framesDrawn") > 5)
        seen = page.execute_script("return window.aquarium.framesReceived")
        _until(lambda: page.execute_script("return window.aquarium.framesReceived") > seen + 5)
        assert len(browser_server[0].pages) == 2
    finally:
        second.quit()
    _until(lambda: len(browser_server[0].pages) == 1)


def _pixel(page, x, y):
    """RGB that the page shows at the canvas pixel under world point (x, y) (both canvases)."""
    return page.execute_script(
        "const v = window.aquarium.view;"
        "return window.aquarium.pixel(Math.floor((arguments[0] - v.x) * v.scale),"
        " Math.floor((arguments[1] - v.y) * v.scale));",
        x,
        y,
    )


def _close(rgb, want, tolerance=4):
    return all(abs(a - b) <= tolerance for a, b in zip(rgb, want, strict=True))


def _place(viewer, positions, headings=None):
    """Pause the shown world and put its agents at `positions` ({slot: (x, y)}; the others in a row at
    the bottom) on the simulation thread."""
    import torch

    def place():
        sim = viewer.simulation
        sim.apply({"type": "pause"})
        sim.apply({"type": "human", "team": None})
        env, w = sim.env, sim.world
        position = torch.stack([torch.tensor([100.0 + 30.0 * i, 740.0]) for i in range(env.capacity)])
        heading = env.state.torch.heading[w].clone()
        alive = torch.ones(env.capacity, dtype=torch.bool)
        for slot, xy in positions.items():
            position[slot] = torch.tensor(xy)
        for slot, h in (headings or {}).items():
            heading[slot] = torch.tensor(h)
        env.set_state(w, position=position, heading=heading, alive=alive)
        return w

    return viewer.on_simulation_thread(place)


def _shows(page, slot, x, y):
    """The page's frame has `slot` at (x, y)."""
    return page.execute_script(
        "const f = window.aquarium.frame; const i = Array.from(f.slots).indexOf(arguments[0]);"
        "return i >= 0 && Math.abs(f.agents[i * 6] - arguments[1]) < 0.01"
        " && Math.abs(f.agents[i * 6 + 1] - arguments[2]) < 0.01 && window.aquarium.framesDrawn > 0;",
        slot,
        x,
        y,
    )


SEA, SHARK_BODY = (172, 206, 231), (92, 112, 135)
PREY_BODY, BACKGROUND = (255, 140, 0), (29, 39, 51)
NO_WEBGL = ("--disable-gpu", "--disable-software-rasterizer")  # chromium then offers no WebGL at all


@pytest.fixture(params=["webgl2", "canvas2d"])
def any_page(request, browser_server):
    """The page asked to draw with WebGL2 at any count: in chromium (SwiftShader, its software GPU), and
    in a chromium without WebGL (the fallback to Canvas 2D)."""
    driver = _browser() if request.param == "webgl2" else _browser(*NO_WEBGL)
    driver.get(browser_server[1] + "?renderer=webgl2")
    _until(lambda: driver.execute_script("return window.aquarium.framesDrawn") > 2)
    assert driver.execute_script("return window.aquarium.renderer") == request.param
    assert (driver.execute_script("return window.aquarium.glName") is not None) == (request.param == "webgl2")
    assert driver.find_element("id", "world-gl").is_displayed() == (request.param == "webgl2")
    yield driver
    driver.quit()


@browser_only
@pytest.mark.slow
def test_each_agent_is_drawn_at_its_pixel_across_the_seam_zoomed_out(any_page, browser_server):
    """At 0.04 canvas pixels per world px with the world's corner at canvas pixel (4, 4), the centre of
    canvas pixel (k, m) is world point (25 k - 87.5, 25 m - 87.5). Prey (radius 20: 0.8 pixels) are
    3 x 3 pixel dots, predators (30: 1.2 pixels) diamonds; a prey at x = 787.5 (pixel 35, the world's
    last column) shows again in pixel 4 (its first) across the seam, and pixel 36 is outside the world."""
    page, viewer = any_page, browser_server[0]
    predator = viewer.simulation.env.prey_capacity

    def centre(k):  # of pixel k, world px
        return 25.0 * k - 87.5

    def pixel(k, m):
        return page.execute_script("return window.aquarium.pixel(arguments[0], arguments[1])", k, m)

    places = {
        slot: (centre(k), centre(m))
        for slot, (k, m) in {0: (8, 10), 1: (16, 10), 2: (35, 20), predator: (24, 16)}.items()
    }
    _place(viewer, places)
    saved = page.execute_script("return window.aquarium.view")
    page.execute_script("window.aquarium.setView({x: -100, y: -100, scale: 0.04})")
    _until(lambda: all(_shows(page, slot, *xy) for slot, xy in places.items()))
    try:
        for k, m in ((8, 10), (7, 9), (9, 11), (16, 10), (35, 20), (34, 20), (4, 20)):
            assert _close(pixel(k, m), PREY_BODY), (k, m, pixel(k, m))
        for k, m in ((11, 10), (12, 10), (19, 10), (5, 20), (33, 20), (24, 22)):
            assert _close(pixel(k, m), SEA), (k, m, pixel(k, m))
        assert _close(pixel(24, 16), SHARK_BODY) and _close(pixel(36, 20), BACKGROUND), (pixel(24, 16), pixel(36, 20))
    finally:
        page.execute_script("window.aquarium.setView(arguments[0])", saved)
        viewer.simulation.playing = True


@browser_only
@pytest.mark.slow
def test_fish_and_sharks_turn_with_their_heading(any_page, browser_server):
    """A prey heading down (+y) covers the point 0.5 r ahead of it (its body) but not 0.5 r to its side;
    a shark heading left (-x) covers 0.6 r ahead (its snout), not 0.6 r across (r: 20 and 30 px)."""
    page, viewer = any_page, browser_server[0]
    predator = viewer.simulation.env.prey_capacity
    _place(viewer, {0: (300.0, 300.0), predator: (500.0, 300.0)}, {0: (0.0, 1.0), predator: (-1.0, 0.0)})
    _until(lambda: _shows(page, 0, 300.0, 300.0) and _shows(page, predator, 500.0, 300.0))
    try:
        assert _close(_pixel(page, 300.0, 310.0), PREY_BODY) and _close(_pixel(page, 310.0, 300.0), SEA)
        assert _close(_pixel(page, 482.0, 300.0), SHARK_BODY) and _close(_pixel(page, 500.0, 318.0), SEA)
    finally:
        viewer.simulation.playing = True


@browser_only
@pytest.mark.slow
def test_a_shark_at_the_edge_is_drawn_across_the_seam_with_its_cone(any_page, browser_server):
    """A predator at x = 795 facing +x in the 800 x 800 world: its snout (30 px radius, nose at 0.9 r)
    and its view cone (200 px, 150 degrees) continue at the left edge, as the MP4 draws them."""
    page, viewer = any_page, browser_server[0]
    predator = viewer.simulation.env.prey_capacity
    _place(viewer, {predator: (795.0, 400.0)}, {predator: (1.0, 0.0)})
    box = page.find_element("id", "ov-view_cones")
    if not box.is_selected():
        box.click()
    _until(lambda: _shows(page, predator, 795.0, 400.0))
    time.sleep(0.3)  # drawn with the overlay
    assert _close(_pixel(page, 10.0, 400.0), SHARK_BODY), _pixel(page, 10.0, 400.0)  # the snout, 15 px across
    # inside the cone across the seam: the sea under the predator's cone colour (230, 40, 40) at alpha 0.25
    cone = [round(0.75 * s + 0.25 * c) for s, c in zip(SEA, (230, 40, 40), strict=True)]
    assert _close(_pixel(page, 60.0, 400.0), cone), _pixel(page, 60.0, 400.0)
    assert _close(_pixel(page, 60.0, 150.0), SEA)  # outside it: the plain sea
    box.click()  # overlays off again for the other tests
    viewer.simulation.playing = True


@browser_only
@pytest.mark.slow
def test_the_legend_shows_fish_and_sharks_in_the_worlds_colours(any_page, browser_server):
    """Each agent icon's most common opaque colour is what the world draws for that mark: a fish's and
    a shark's body 0.5 r ahead of its centre zoomed in, a prey's dot and a predator's diamond at their
    centres zoomed out (0.04 canvas pixels per world px)."""
    page, viewer = any_page, browser_server[0]
    legend = page.find_element("id", "legend").text
    assert "fish: prey" in legend and "shark: predator" in legend and "predator (zoomed out)" in legend
    icons = page.execute_script(
        "const out = {}; document.querySelectorAll('canvas.icon').forEach((c) => {"
        " const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data, counts = {};"
        " for (let i = 0; i < d.length; i += 4) if (d[i + 3] === 255) {"
        "  const key = `${d[i]},${d[i + 1]},${d[i + 2]}`; counts[key] = (counts[key] || 0) + 1; }"
        " const top = Object.keys(counts).sort((a, b) => counts[b] - counts[a])[0];"
        " out[c.dataset.icon] = top ? top.split(',').map(Number) : null; }); return out;"
    )
    assert len(icons) == 8 and all(icons[name] is not None for name in ("prey", "predator", "prey-dot"))
    predator = viewer.simulation.env.prey_capacity
    _place(viewer, {0: (300.0, 300.0), predator: (500.0, 300.0)}, {0: (1.0, 0.0), predator: (1.0, 0.0)})
    _until(lambda: _shows(page, 0, 300.0, 300.0) and _shows(page, predator, 500.0, 300.0))
    saved = page.execute_script("return window.aquarium.view")
    try:
        assert icons["prey"] == _pixel(page, 310.0, 300.0) == list(PREY_BODY)
        assert icons["predator"] == _pixel(page, 515.0, 300.0) == list(SHARK_BODY)
        page.execute_script("window.aquarium.setView({x: 0, y: 0, scale: 0.04})")
        assert icons["prey-dot"] == _pixel(page, 300.0, 300.0) == list(PREY_BODY)
        assert icons["predator-diamond"] == _pixel(page, 500.0, 300.0) == list(SHARK_BODY)
    finally:
        page.execute_script("window.aquarium.setView(arguments[0])", saved)
        viewer.simulation.playing = True


def _canvas_point(page, x, y):
    """Offsets from the canvas' centre (Selenium's origin) of world point (x, y)."""
    return page.execute_script(
        "const v = window.aquarium.view, c = document.getElementById('world'), r = c.getBoundingClientRect();"
        "const ratio = window.devicePixelRatio || 1;"
        "return [(arguments[0] - v.x) * v.scale / ratio - r.width / 2,"
        " (arguments[1] - v.y) * v.scale / ratio - r.height / 2];",
        x,
        y,
    )


@browser_only
@pytest.mark.slow
def test_click_inspects_an_agent_and_drag_moves_it(page, browser_server):
    import torch
    from selenium.webdriver.common.action_chains import ActionChains

    viewer = browser_server[0]
    world = _place(viewer, {3: (300.0, 300.0)})
    canvas = page.find_element("id", "world")
    _until(lambda: _shows(page, 3, 300.0, 300.0))
    dx, dy = _canvas_point(page, 300.0, 300.0)
    ActionChains(page).move_to_element_with_offset(canvas, round(dx), round(dy)).click().perform()
    _until(lambda: _header(page)["inspect"] is not None)
    info = _header(page)["inspect"]
    env = viewer.simulation.env
    want = viewer.on_simulation_thread(lambda: env.outputs.observations["prey"][world, 3].tolist())
    assert info["slot"] == 3 and info["team"] == "prey" and info["alive"]
    np.testing.assert_allclose(info["observation"], want, atol=1e-4)  # set_state's observations of slot 3
    assert "prey (slot 3)" in page.find_element("id", "inspect").text
    # drag it 200 px right and 100 px down (world px): the server puts it there, nothing else moves
    before = viewer.on_simulation_thread(lambda: env.state.torch.position[world].clone())
    tx, ty = _canvas_point(page, 500.0, 400.0)
    chain = ActionChains(page).move_to_element_with_offset(canvas, round(dx), round(dy)).click_and_hold()
    for k in range(1, 6):
        chain = chain.move_to_element_with_offset(canvas, round(dx + (tx - dx) * k / 5), round(dy + (ty - dy) * k / 5))
    chain.release().perform()
    after = before.clone()
    pixel = 1.0 / page.execute_script("return window.aquarium.view.scale")  # one canvas pixel, world px

    def moved():
        now = viewer.on_simulation_thread(lambda: env.state.torch.position[world].clone())
        after.copy_(now)
        return float(torch.linalg.vector_norm(now[3] - torch.tensor([500.0, 400.0]))) <= 2 * pixel

    _until(moved)
    others = [i for i in range(env.capacity) if i != 3]
    assert torch.equal(after[others], before[others])
    viewer.simulation.playing = True


@browser_only
@pytest.mark.slow
def test_a_drag_outside_the_world_is_refused_by_the_state_api(browser_server):
    viewer, url = browser_server
    port = int(url.rsplit(":", 1)[1].strip("/"))
    with connect(f"ws://127.0.0.1:{port}/ws", max_size=None) as ws:
        ws.send(json.dumps({"type": "move", "slot": 0, "x": 900.0, "y": 10.0}))
        while isinstance(reply := ws.recv(timeout=10), bytes) or json.loads(reply)["type"] != "error":
            pass
    assert "position must lie in [0, 800.0) x [0, 800.0)" in json.loads(reply)["message"]


@browser_only
@pytest.mark.slow
def test_the_timeline_shows_past_frames_and_returns_to_live(page, browser_server):
    _until(lambda: page.execute_script("return window.aquarium.history.length") > 20)
    page.execute_script(
        "const t = document.getElementById('timeline'); t.value = t.min; t.dispatchEvent(new Event('input'));"
    )
    _until(lambda: page.execute_script("return window.aquarium.scrubbing"))
    shown = _header(page)["step"]
    first = page.execute_script("return window.aquarium.history[0].frame.header.step")
    assert shown <= first + 2  # the oldest kept frame (or one after it, if it just fell out)
    received = page.execute_script("return window.aquarium.framesReceived")
    _until(lambda: page.execute_script("return window.aquarium.framesReceived") > received + 5)
    assert _header(page)["step"] == shown  # the run goes on, the page keeps the past frame
    assert "timeline: past frame" in page.find_element("id", "step-label").text
    page.find_element("id", "live").click()
    _until(lambda: not page.execute_script("return window.aquarium.scrubbing") and _header(page)["step"] > shown)


@browser_only
@pytest.mark.slow
def test_each_page_has_its_own_overlays(page, browser_server):
    viewer = browser_server[0]
    second = _browser()
    try:
        second.get(browser_server[1])
        _until(lambda: second.execute_script("return window.aquarium.framesDrawn") > 2)
        second.find_element("id", "ov-flow").click()
        _until(lambda: second.execute_script("return window.aquarium.frame.flow !== null"))
        time.sleep(0.5)
        assert page.execute_script("return window.aquarium.frame.flow") is None  # the first page's frames
        assert not page.find_element("id", "ov-flow").is_selected()
        assert sorted(p.overlays["flow"] for p in viewer.pages) == [False, True]
    finally:
        second.quit()


class _GatedRenderer:
    """The Renderer, built only once `gate` is set (a first build's kernel compilation, made slow)."""

    def __init__(self, gate):
        self.gate = gate

    def __call__(self, env, **options):
        from aquarium_warp.render import Renderer

        assert self.gate.wait(60)
        return Renderer(env, **options)


@browser_only
@pytest.mark.slow
def test_record_waits_for_the_renderer_without_stopping_the_page_and_ends_with_its_page(tmp_path, monkeypatch):
    gate = threading.Event()
    monkeypatch.setattr("aquarium_warp.viewer.server.Renderer", _GatedRenderer(gate))
    viewer = Viewer(Simulation(ViewOptions(device="cpu")), record_dir=str(tmp_path))
    with serve(viewer) as port:
        driver = _browser()
        try:
            driver.get(f"http://127.0.0.1:{port}/")
            _until(lambda: driver.execute_script("return window.aquarium.framesDrawn") > 2)
            record = driver.find_element("id", "record")
            record.click()
            _until(lambda: _header(driver)["recording"] == "preparing")
            assert not record.is_enabled() and "Preparing" in record.text
            step = _header(driver)["step"]
            _until(lambda: _header(driver)["step"] > step + 10)  # the run and the page go on meanwhile
            gate.set()
            _until(lambda: _header(driver)["recording"] == "on" and record.is_enabled())
            assert record.text == "Stop recording"
            frames = viewer.frames
            _until(lambda: viewer.frames > frames + 10)
        finally:
            driver.quit()
        _until(lambda: viewer.recording == "off")  # the page that started it closed
        videos = list(tmp_path.glob("*.mp4"))
        assert len(videos) == 1 and videos[0].stat().st_size > 1000
        assert len(read_trajectory(str(videos[0].with_suffix(".json")))["frames"]) >= 10


class _Errors(logging.Handler):
    def __init__(self):
        super().__init__(logging.ERROR)
        self.records = []

    def emit(self, record):
        self.records.append(record)


@pytest.mark.slow
def test_a_page_closed_while_the_recorder_is_prepared_leaves_no_traceback_and_no_recording(tmp_path, monkeypatch):
    gate = threading.Event()
    monkeypatch.setattr("aquarium_warp.viewer.server.Renderer", _GatedRenderer(gate))
    errors = _Errors()
    for name in ("uvicorn.error", "asyncio"):
        logging.getLogger(name).addHandler(errors)
    try:
        viewer = Viewer(Simulation(ViewOptions(device="cpu")), record_dir=str(tmp_path))
        with serve(viewer) as port:
            with connect(f"ws://127.0.0.1:{port}/ws", max_size=None) as ws:
                ws.recv(timeout=10)
                ws.send('{"type": "record", "on": true}')
                _until(lambda: viewer.recording == "preparing")
            _until(lambda: not viewer.pages)
            gate.set()  # ready after the page has gone: its notice has nowhere to go
            _until(lambda: viewer.recording == "off")
            frames = viewer.frames
            _until(lambda: viewer.frames > frames + 5)
    finally:
        for name in ("uvicorn.error", "asyncio"):
            logging.getLogger(name).removeHandler(errors)
    assert errors.records == [] and list(tmp_path.iterdir()) == []


@browser_only
@pytest.mark.slow
def test_the_page_reconnects_when_the_server_restarts():
    viewer = Viewer(Simulation(ViewOptions(device="cpu")))
    with serve(viewer) as port:
        driver = _browser()
        driver.get(f"http://127.0.0.1:{port}/")
        _until(lambda: driver.execute_script("return window.aquarium.framesDrawn") > 2)
    try:
        _until(lambda: not driver.execute_script("return window.aquarium.connected"))
        assert "reconnecting" in driver.find_element("id", "step-label").text
        again = Viewer(Simulation(ViewOptions(device="cpu", worlds=2)))
        with serve(again, port):
            _until(lambda: driver.execute_script("return window.aquarium.connections") == 2, timeout=30)
            _until(lambda: _header(driver)["num_worlds"] == 2)  # frames of the new server
    finally:
        driver.quit()


# ---------------------------------------------------------------------- attach(env), the widget, train --view
def _env_and_drivers(seed=0):
    from aquarium_warp.config import AquariumConfig
    from aquarium_warp.drivers import make_drivers
    from aquarium_warp.env import BatchedAquarium

    env = BatchedAquarium(AquariumConfig(), num_worlds=2, device="cpu", seed=seed)
    return env, make_drivers({"prey": "turnaway", "predator": "naivchase"}, env, seed=seed)


def _frame_of(ws) -> tuple[dict, np.ndarray, np.ndarray]:
    """(header, positions, slots) of the next frame."""
    while True:
        data = ws.recv(timeout=10)
        if isinstance(data, bytes):
            header, agents = unpack_frame(data)
            return header, agents["position"], agents["slots"]


def test_attach_serves_the_env_as_the_script_steps_it():
    from aquarium_warp.viewer import attach

    env, drivers = _env_and_drivers()
    seen: dict[int, np.ndarray] = {}  # world 1's positions after each step, by step
    with attach(env, world=1) as viewer, connect(viewer.url.replace("http", "ws") + "ws", max_size=None) as ws:
        headers = []
        for _ in range(60):
            env.step({team: driver() for team, driver in drivers.items()})
            seen[int(env.state.torch.world_step[1])] = env.state.torch.position[1].numpy().copy()
            time.sleep(0.02)
            header, position, slots = _frame_of(ws)
            headers.append(header)
            if header["step"] in seen:  # world 1 as it was after that step, to half a quantum (on the torus)
                off = (position - seen[header["step"]][slots] + 400.0) % 800.0 - 400.0
                assert np.abs(off).max() <= 800 / 131072
        steps = [h["step"] for h in headers]
        assert steps == sorted(steps) and steps[-1] > 30 and not headers[-1]["controls"]
        assert {h["world"] for h in headers} == {1}
        ws.send('{"type": "play"}')  # the script steps the env: the page's controls are refused
        while isinstance(reply := ws.recv(timeout=10), bytes):
            pass
        assert "stepped by its own code" in json.loads(reply)["message"]
    assert "step" not in env.__dict__  # detached: the env's own method again


def test_a_drag_on_an_attached_env_moves_the_agent_before_the_next_step():
    """The attached env after the drag and a step equals a twin env moved by `set_state` and stepped."""
    from aquarium_warp.viewer import attach
    from aquarium_warp.viewer.simulation import move_agent

    env, drivers = _env_and_drivers(seed=3)
    twin, twin_drivers = _env_and_drivers(seed=3)
    with attach(env) as viewer, connect(viewer.url.replace("http", "ws") + "ws", max_size=None) as ws:
        _frame_of(ws)
        ws.send('{"type": "move", "slot": 2, "x": 123.5, "y": 456.25}')
        _until(lambda: viewer.run._moves)  # checked and queued for the next step
        env.step({team: driver() for team, driver in drivers.items()})
    move_agent(twin, 0, 2, 123.5, 456.25)
    twin.step({team: driver() for team, driver in twin_drivers.items()})
    assert torch_equal(env.state.torch.position, twin.state.torch.position)
    assert torch_equal(env.state.torch.velocity, twin.state.torch.velocity)


def torch_equal(a, b) -> bool:
    import torch

    return bool(torch.equal(a, b))


def test_attach_refuses_a_port_in_use_and_bad_options():
    from aquarium_warp.viewer import attach

    env, _ = _env_and_drivers()
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        with pytest.raises(
            ValueError, match=f"port {port}: cannot serve on 127.0.0.1:{port} \\(Address already in use\\)"
        ):
            attach(env, port=port)
    with pytest.raises(ValueError, match=r"world=2 must be an integer in \[0, 1\]"):
        attach(env, world=2)
    with pytest.raises(ValueError, match=r"port=70000 must be an integer in \[0, 65535\]"):
        attach(env, port=70000)
    assert "step" not in env.__dict__


def test_the_notebook_widget_shows_the_attached_page():
    pytest.importorskip("anywidget", reason="the notebook extra: pip install 'aquarium-warp[notebook]'")
    import urllib.request

    from aquarium_warp.viewer.widget import ViewerWidget

    env, _ = _env_and_drivers()
    view = ViewerWidget(env, height=500)
    try:
        state = view.get_state()
        assert state["url"] == view.attached.url and state["height"] == 500
        assert 'id="world"' in urllib.request.urlopen(state["url"], timeout=10).read().decode()
    finally:
        view.close()
    with pytest.raises(ValueError, match=r"height=50 must be an integer in \[200, 4000\]"):
        ViewerWidget(env, height=50)


@pytest.mark.slow
def test_the_notebook_example_runs_headless():
    """docs/notebooks/viewer.ipynb's code cells, run in order as a kernel would."""
    pytest.importorskip("anywidget", reason="the notebook extra: pip install 'aquarium-warp[notebook]'")
    path = os.path.join(os.path.dirname(__file__), "..", "..", "docs", "notebooks", "viewer.ipynb")
    with open(path, encoding="utf-8") as f:
        notebook = json.load(f)
    namespace: dict = {}
    cells = ["".join(cell["source"]) for cell in notebook["cells"] if cell["cell_type"] == "code"]
    for source in cells[:-1]:
        exec(compile(source, path, "exec"), namespace)
    view = namespace["view"]
    try:
        assert int(namespace["env"].state.torch.world_step[0]) == 300
        with connect(view.url.replace("http", "ws") + "ws", max_size=None) as ws:
            _until(lambda: _frame_of(ws)[0]["step"] == 300)  # the script has stopped: its last state is shown
    finally:
        exec(compile(cells[-1], path, "exec"), namespace)
    assert not view.attached._thread.is_alive()


@pytest.mark.slow
def test_train_view_serves_the_training_worlds(tmp_path, capsys):
    pytest.importorskip("rsl_rl", reason="the training extra")
    code = main(
        ["train", "--preset", "tiny", "--team", "prey", "--device", "cpu", "--iterations", "1", "--view", "0"]
        + ["--log-dir", str(tmp_path / "run"), "--export", "none", "--quiet"]
    )
    out = capsys.readouterr().out
    assert code == 0 and "aquarium-warp train: the training worlds are on http://127.0.0.1:" in out, out


REPO = os.path.join(os.path.dirname(__file__), "..", "..")


def _docs_replay_pages(site_dir) -> dict[str, str]:
    """The replay pages of the docs site, as its build makes them (mkdocs.yml's hooks), by site path."""
    from mkdocs.config import load_config
    from mkdocs.structure.files import get_files

    config = load_config(os.path.join(REPO, "mkdocs.yml"), site_dir=str(site_dir))
    files = config.plugins.on_files(get_files(config), config=config)
    return {f.src_uri: f.content_string for f in files if f.src_uri.startswith("replays/") and f.generated_by}


@pytest.mark.slow
def test_the_docs_build_generates_each_replay_page_from_the_viewer(tmp_path):
    pages = _docs_replay_pages(tmp_path)
    trajectories = sorted(name for name in os.listdir(os.path.join(REPO, "docs", "replays")) if name.endswith(".json"))
    assert trajectories and sorted(pages) == [f"replays/{name[:-5]}.html" for name in trajectories]
    for name in trajectories:
        out = tmp_path / f"{name[:-5]}.html"  # what `aquarium-warp view --replay NAME.json --out NAME.html` writes
        assert main(["view", "--replay", os.path.join(REPO, "docs", "replays", name), "--out", str(out)]) == 0
        assert pages[f"replays/{name[:-5]}.html"] == out.read_text()


@browser_only
@pytest.mark.slow
def test_a_docs_replay_page_plays_pauses_and_steps_through_its_trajectory(tmp_path):
    page_path = tmp_path / "prey-b.html"
    page_path.write_text(_docs_replay_pages(tmp_path / "site")["replays/prey-b.html"], encoding="utf-8")
    frames = read_trajectory(os.path.join(REPO, "docs", "replays", "prey-b.json"))["frames"]
    driver = _browser()
    try:
        driver.get(page_path.as_uri())  # from disk, no server
        _until(lambda: driver.execute_script("return window.aquarium.framesDrawn") > 5)
        _until(lambda: _header(driver)["step"] > 2)  # it plays
        driver.find_element("id", "play").click()
        paused = _header(driver)["step"]
        time.sleep(0.3)
        assert _header(driver)["step"] == paused
        driver.find_element("id", "step").click()
        _until(lambda: _header(driver)["step"] == paused + 1)
        shown = frames[paused + 1]
        header = _header(driver)
        assert header["n"] == len(shown["slot"]) and header["episode_captures"] == shown["episode_captures"]
        agents = np.array(driver.execute_script("return Array.from(window.aquarium.frame.agents)")).reshape(-1, 6)
        # positions quantised to 800 px / 65536, as the server's frames
        np.testing.assert_allclose(agents[:, 0], shown["x"], atol=800 / 65536)
        np.testing.assert_allclose(agents[:, 1], shown["y"], atol=800 / 65536)
    finally:
        driver.quit()

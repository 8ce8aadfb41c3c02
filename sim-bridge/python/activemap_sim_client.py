"""An external simulator that takes the built-in ``sim`` node's place in an activemap dataflow.

Run by the launcher as a ``path:`` node (see ../BRIDGE.md for a dataflow). It speaks Zenoh
through the ``eclipse-zenoh`` package (pinned to the Rust side's version, 1.10.2) and plays the
simulator role in lockstep:

1. read the run from the environment the launcher sets (``ACTIVEMAP_RUN_ID``,
   ``ACTIVEMAP_ZENOH_CONNECT``, ``ACTIVEMAP_INPUTS``, ``ACTIVEMAP_OUTPUTS``, ``ACTIVEMAP_CONTROL``,
   ``ACTIVEMAP_CONFIG``, ``ACTIVEMAP_MAX_STEPS``);
2. subscribe, then announce ``<control>/ready/<node id>`` every 200 ms until ``<control>/start``
   arrives (the start barrier: nobody sends before every subscriber exists);
3. publish frame 0 (RgbdFrame, TruePose, EpisodeStatus) at the start pose; then, for every Action
   whose ``step`` is the last frame's id, apply it and publish the next frame;
4. stop after ``max_steps`` actions, a ``stop`` action, the end of the action stream, a
   ``<control>/stop`` broadcast or SIGTERM; then send end-of-stream (an empty payload) on every
   output and exit 0.

Scenes (``config.scene``):

- ``box``: :class:`BoxRoomScene`, a textured box room with two boxes, ray cast in pure Python
  (no numpy), so the bridge runs in CI. 64x64 renders in about 0.1 s.
- :class:`HabitatSimAdapter` shows where habitat-sim plugs in (``scene: habitat:<scene file>``).
  habitat-sim cannot be installed on the project's machines, so that path is untested here.

Config keys (the node's ``config:`` in the dataflow): ``scene`` ("box"), ``width``/``height``
(64), ``hfov_deg`` (90), ``max_steps`` (2000; ``--max-steps`` overrides), ``forward_step``
(0.05 m), ``turn_deg`` (5), ``seed`` (0), ``noise`` (``none``; the built-in simulator's syntax
and models, see :mod:`activemap_noise`), ``lockstep`` (must be true), ``log`` (optional path:
one JSON line per frame sent and per action received). Any other key is refused, naming it.
"""

import json
import math
import os
import signal
import struct
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import activemap_bridge as codec  # noqa: E402
import activemap_noise as noise  # noqa: E402

STEP_SECONDS = 0.1
CAMERA_HEIGHT = 0.88
AGENT_RADIUS = 0.1


def intrinsics_from_hfov(width, height, hfov_deg):
    """(fx, fy, cx, cy) of a pinhole with horizontal FOV ``hfov_deg`` and square pixels; pixel i
    covers u in [i - 0.5, i + 0.5), so the image centre is at (w - 1) / 2 (SPEC section 2)."""
    fx = 0.5 * width / math.tan(0.5 * math.radians(hfov_deg))
    return fx, fx, 0.5 * width - 0.5, 0.5 * height - 0.5


def quaternion_from_matrix(m):
    """Unit quaternion (x, y, z, w) of a 3x3 rotation matrix given as rows (Shepperd's method)."""
    trace = m[0][0] + m[1][1] + m[2][2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(1.0 + trace)
        return ((m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, 0.25 * s)
    if m[0][0] > m[1][1] and m[0][0] > m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2])
        return (0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s, (m[2][1] - m[1][2]) / s)
    if m[1][1] > m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2])
        return ((m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s, (m[0][2] - m[2][0]) / s)
    s = 2.0 * math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1])
    return ((m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s, (m[1][0] - m[0][1]) / s)


def camera_axes(yaw):
    """World directions of the OpenCV optical axes (x right, y down, z forward) of a level camera
    on a robot with heading ``yaw`` (world z up, REP-103 base: x forward, y left)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return (s, -c, 0.0), (0.0, 0.0, -1.0), (c, s, 0.0)


def camera_pose(x, y, yaw, floor_z=0.0):
    """T_world_camera of the robot at planar pose (x, y, yaw): (translation, quaternion xyzw)."""
    ax, ay, az = camera_axes(yaw)
    rows = [[ax[r], ay[r], az[r]] for r in range(3)]
    return (x, y, floor_z + CAMERA_HEIGHT), quaternion_from_matrix(rows)


class BoxRoomScene:
    """A box room (floor at z = 0) with axis-aligned boxes standing on the floor, ray cast per
    pixel. Surfaces carry a procedural texture (a checkerboard of 0.25 m cells modulated by a
    fine hashed pattern) so that photometric tracking has gradients everywhere."""

    def __init__(self, room=((-2.0, -1.5), (2.0, 1.5)), height=2.5, boxes=None):
        (self.x0, self.y0), (self.x1, self.y1) = room
        self.height = height
        # Each box: ((xmin, ymin), (xmax, ymax), top z).
        self.boxes = boxes if boxes is not None else [
            ((0.8, 0.5), (1.4, 1.1), 0.9),
            ((-1.5, -1.2), (-0.9, -0.4), 1.4),
        ]
        self.start = (0.0, 0.0, 0.0)

    def blocked(self, x, y, radius=AGENT_RADIUS):
        """True when a cylinder of ``radius`` at (x, y) overlaps a wall or a box."""
        if not (self.x0 + radius < x < self.x1 - radius and self.y0 + radius < y < self.y1 - radius):
            return True
        for (bx0, by0), (bx1, by1), _ in self.boxes:
            dx = max(bx0 - x, 0.0, x - bx1)
            dy = max(by0 - y, 0.0, y - by1)
            if dx * dx + dy * dy < radius * radius:
                return True
        return False

    @staticmethod
    def _texture(u, v, hue):
        """RGB of the procedural texture at surface coordinates (u, v) metres."""
        cell = (math.floor(u * 4.0) + math.floor(v * 4.0)) & 1
        fine = ((int(math.floor(u * 40.0)) * 73856093) ^ (int(math.floor(v * 40.0)) * 19349663)) & 63
        shade = (0.55 + 0.35 * cell) * (0.8 + fine / 160.0)
        return tuple(min(255, int(255.0 * shade * h)) for h in hue)

    def cast(self, origin, direction):
        """(t, rgb) of the first surface along origin + t * direction (t > 0), or None."""
        ox, oy, oz = origin
        dx, dy, dz = direction
        best = math.inf
        hit = None
        # Room interior: the ray leaves through one of the six faces.
        for axis, lo, hi, o, d in ((0, self.x0, self.x1, ox, dx), (1, self.y0, self.y1, oy, dy),
                                   (2, 0.0, self.height, oz, dz)):
            if d != 0.0:
                t = ((hi if d > 0.0 else lo) - o) / d
                if 0.0 < t < best:
                    best, hit = t, (axis, d > 0.0, "room")
        # Boxes: slab test for the entry point.
        for index, ((bx0, by0), (bx1, by1), top) in enumerate(self.boxes):
            t_near, t_far, face = -math.inf, math.inf, None
            for axis, lo, hi, o, d in ((0, bx0, bx1, ox, dx), (1, by0, by1, oy, dy), (2, 0.0, top, oz, dz)):
                if d == 0.0:
                    if not lo <= o <= hi:
                        t_near = math.inf
                    continue
                ta, tb = (lo - o) / d, (hi - o) / d
                if ta > tb:
                    ta, tb = tb, ta
                if ta > t_near:
                    t_near, face = ta, (axis, d < 0.0, index)
                t_far = min(t_far, tb)
            if face is not None and 0.0 < t_near <= t_far and t_near < best:
                best, hit = t_near, face
        if hit is None:
            return None
        px, py, pz = ox + best * dx, oy + best * dy, oz + best * dz
        axis, positive, what = hit
        hues = ((1.0, 0.75, 0.6), (0.6, 0.8, 1.0), (0.8, 1.0, 0.7), (1.0, 1.0, 0.85))
        if what == "room":
            hue = hues[axis] if axis < 2 else (hues[2] if not positive else hues[3])
        else:
            hue = (1.0, 0.5 + 0.3 * what, 0.3)
        u, v = ((py, pz), (px, pz), (px, py))[axis]
        return best, self._texture(u, v, hue)


class RayCastCamera:
    """Renders RGB8 and float32 z-depth of a :class:`BoxRoomScene` through a pinhole."""

    def __init__(self, width, height, hfov_deg, max_depth=10.0):
        self.width, self.height = width, height
        self.intrinsics = intrinsics_from_hfov(width, height, hfov_deg)
        fx, fy, cx, cy = self.intrinsics
        # Ray through pixel (i, j) in the camera frame, scaled to z = 1: t is then the z-depth.
        self.rays = [((i - cx) / fx, (j - cy) / fy) for j in range(height) for i in range(width)]
        self.max_depth = max_depth

    def render(self, scene, x, y, yaw, floor_z=0.0):
        """(rgb bytes, depth bytes) at the robot's planar pose; depth 0 = no reading."""
        ax, ay, az = camera_axes(yaw)
        origin = (x, y, floor_z + CAMERA_HEIGHT)
        rgb = bytearray(3 * self.width * self.height)
        depth = [0.0] * (self.width * self.height)
        for k, (rx, ry) in enumerate(self.rays):
            direction = tuple(rx * ax[c] + ry * ay[c] + az[c] for c in range(3))
            hit = scene.cast(origin, direction)
            if hit is None:
                continue
            t, colour = hit
            rgb[3 * k:3 * k + 3] = bytes(colour)
            depth[k] = t if t <= self.max_depth else 0.0
        return bytes(rgb), struct.pack(f"<{len(depth)}f", *depth)


class BoxRoomSimulator:
    """Habitat-style discrete motion in a :class:`BoxRoomScene`: ``forward`` moves
    ``forward_step`` metres along the heading unless the agent's cylinder would overlap a wall or
    box (then it stays: no sliding), ``turn_left``/``turn_right`` turn by ``turn_deg``."""

    def __init__(self, width=64, height=64, hfov_deg=90.0, forward_step=0.05, turn_deg=5.0, actuation=None):
        self.actuation = actuation
        self.scene = BoxRoomScene()
        self.camera = RayCastCamera(width, height, hfov_deg)
        self.width, self.height = width, height
        self.forward_step = forward_step
        self.turn = math.radians(turn_deg)
        self.x, self.y, self.yaw = self.scene.start

    @property
    def intrinsics(self):
        """(fx, fy, cx, cy) in pixels."""
        return self.camera.intrinsics

    def step(self, action):
        """Applies ``forward``, ``turn_left`` or ``turn_right``; returns True on a collision."""
        wrap = lambda a: (a + math.pi) % (2.0 * math.pi) - math.pi  # noqa: E731
        if action == "forward":
            distance, dyaw = (self.actuation.forward(self.forward_step) if self.actuation
                              else (self.forward_step, 0.0))
            # Along the chord of the arc: the old heading plus half the heading change.
            along = self.yaw + 0.5 * dyaw
            nx = self.x + distance * math.cos(along)
            ny = self.y + distance * math.sin(along)
            blocked = self.scene.blocked(nx, ny)
            if not blocked:
                self.x, self.y = nx, ny
            if dyaw != 0.0:
                self.yaw = wrap(self.yaw + dyaw)
            return blocked
        elif action in ("turn_left", "turn_right"):
            sign = 1.0 if action == "turn_left" else -1.0
            angle = self.actuation.turn(self.turn) if self.actuation else self.turn
            self.yaw = wrap(self.yaw + sign * angle)
        else:
            raise ValueError(f"unknown action {action!r}")
        return False

    def render(self):
        """(rgb bytes, depth bytes) at the true pose."""
        return self.camera.render(self.scene, self.x, self.y, self.yaw)

    def true_pose(self):
        """T_world_camera as (translation, quaternion xyzw); ground truth, evaluation only."""
        return camera_pose(self.x, self.y, self.yaw)


class HabitatSimAdapter:
    """Where habitat-sim plugs in: the same interface as :class:`BoxRoomSimulator` (``step``,
    ``render``, ``true_pose``, ``intrinsics``) over a ``habitat_sim.Simulator``.

    Not run on the project's machines (habitat-sim is not installable there); written against
    habitat-sim 0.3's documented API. Habitat's world is y-up with OpenGL cameras (x right, y up,
    z backwards); the pipeline's world is z-up with OpenCV cameras (SPEC section 2), so poses are
    converted with a +90 degree rotation about x (world) and diag(1, -1, -1) (camera).
    """

    def __init__(self, scene_file, width=64, height=64, hfov_deg=90.0, forward_step=0.05, turn_deg=5.0):
        import habitat_sim  # noqa: PLC0415 (optional dependency)

        backend = habitat_sim.SimulatorConfiguration()
        backend.scene_id = scene_file
        sensors = []
        for uuid, kind in (("color", habitat_sim.SensorType.COLOR), ("depth", habitat_sim.SensorType.DEPTH)):
            spec = habitat_sim.CameraSensorSpec()
            spec.uuid, spec.sensor_type = uuid, kind
            spec.resolution = [height, width]
            spec.hfov = hfov_deg
            spec.position = [0.0, CAMERA_HEIGHT, 0.0]
            sensors.append(spec)
        agent = habitat_sim.agent.AgentConfiguration()
        agent.sensor_specifications = sensors
        agent.action_space = {
            "forward": habitat_sim.agent.ActionSpec("move_forward", habitat_sim.agent.ActuationSpec(amount=forward_step)),
            "turn_left": habitat_sim.agent.ActionSpec("turn_left", habitat_sim.agent.ActuationSpec(amount=turn_deg)),
            "turn_right": habitat_sim.agent.ActionSpec("turn_right", habitat_sim.agent.ActuationSpec(amount=turn_deg)),
        }
        self.sim = habitat_sim.Simulator(habitat_sim.Configuration(backend, [agent]))
        self.width, self.height = width, height
        self.intrinsics = intrinsics_from_hfov(width, height, hfov_deg)

    def step(self, action):
        """Applies an action; returns True on a collision (Habitat slides along walls)."""
        return bool(self.sim.step(action).get("collided", False))

    def render(self):
        """(rgb bytes, depth bytes): RGBA to RGB8; Habitat depth is already z-depth in metres."""
        obs = self.sim.get_sensor_observations()
        rgb = obs["color"][..., :3].tobytes()
        depth = obs["depth"].astype("<f4").tobytes()
        return rgb, depth

    def true_pose(self):
        """T_world_camera in the pipeline's frames, from the colour sensor's Habitat pose."""
        state = self.sim.get_agent(0).get_state().sensor_states["color"]
        p, q = state.position, state.rotation  # Habitat: y-up world, OpenGL camera
        r_hab = _matrix_from_quaternion((q.x, q.y, q.z, q.w))
        # z-up world from y-up world: (x, y, z) -> (x, -z, y).
        up = [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]
        gl_from_cv = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
        r = _matmul(_matmul(up, r_hab), gl_from_cv)
        t = [sum(up[i][k] * p[k] for k in range(3)) for i in range(3)]
        return tuple(t), quaternion_from_matrix(r)


def _matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def _matrix_from_quaternion(q):
    x, y, z, w = q
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]


#: The config keys this client reads.
CONFIG_KEYS = ("scene", "width", "height", "hfov_deg", "max_steps", "forward_step", "turn_deg",
               "seed", "noise", "lockstep", "log")


class NoisySensor:
    """A simulator whose ``render`` gets the sensor noise of ``sensor`` (an
    :class:`activemap_noise.SensorNoise`); everything else is the simulator's."""

    def __init__(self, sim, sensor):
        self._sim, self._sensor = sim, sensor

    def __getattr__(self, name):
        return getattr(self._sim, name)

    def render(self):
        rgb, depth = self._sim.render()
        return self._sensor.apply(rgb, depth, self._sim.width)


def make_simulator(config):
    """The simulator a node config asks for (``scene: box`` or ``scene: habitat:<file>``), with
    the configured noise. Unknown keys and bad values are errors naming the key."""
    unknown = sorted(set(config) - set(CONFIG_KEYS))
    if unknown:
        raise ValueError(
            f"config: unknown key(s) {', '.join(unknown)}; this client reads {', '.join(CONFIG_KEYS)} "
            "(placement keys such as up_axis, transform and floor, and robot, are the built-in "
            "simulator's: see sim-bridge/BRIDGE.md)")
    if config.get("lockstep", True) is not True:
        raise ValueError("config lockstep: this client runs lockstep only (one frame per action)")
    seed = config.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"config seed: expected an integer >= 0, got {seed!r}")
    noise_config = noise.parse_noise(config.get("noise"))
    sensor = noise.SensorNoise(noise_config, seed)
    actuation = noise.ActuationNoise(noise_config, seed)
    sim = _make_clean_simulator(config, actuation if actuation.active() else None)
    return NoisySensor(sim, sensor) if sensor.active() else sim


def _make_clean_simulator(config, actuation):
    scene = config.get("scene", "box")
    kwargs = dict(
        width=int(config.get("width", 64)),
        height=int(config.get("height", 64)),
        hfov_deg=float(config.get("hfov_deg", 90.0)),
        forward_step=float(config.get("forward_step", 0.05)),
        turn_deg=float(config.get("turn_deg", 5.0)),
    )
    if kwargs["width"] < 1 or kwargs["height"] < 1:
        raise ValueError(f"config width/height must be >= 1, got {kwargs['width']}x{kwargs['height']}")
    if scene == "box":
        return BoxRoomSimulator(actuation=actuation, **kwargs)
    if scene.startswith("habitat:"):
        if actuation is not None:
            raise ValueError("config noise.actuation: not supported with habitat-sim here; use its own "
                             "noisy actions (habitat_sim.agent.controls.pyrobot_noisy_controls)")
        return HabitatSimAdapter(scene[len("habitat:"):], **kwargs)
    raise ValueError(f"config scene must be 'box' or 'habitat:<file>', got {scene!r}")


class ExternalNode:
    """The Zenoh side of an external node: the launcher's environment, publishers with sequence
    numbers, subscribers, the start barrier, the stop broadcast and end-of-stream."""

    def __init__(self, environ=os.environ):
        import zenoh  # noqa: PLC0415 (only the live node needs it)

        def need(name):
            if name not in environ:
                raise RuntimeError(f"{name} is not set: run this program as a `path:` node of an activemap dataflow")
            return environ[name]

        self.node_id = need("ACTIVEMAP_NODE_ID")
        self.control = need("ACTIVEMAP_CONTROL")
        self.inputs = json.loads(need("ACTIVEMAP_INPUTS"))
        self.outputs = json.loads(need("ACTIVEMAP_OUTPUTS"))
        self.config = json.loads(environ.get("ACTIVEMAP_CONFIG", "null")) or {}
        max_steps = environ.get("ACTIVEMAP_MAX_STEPS")
        self.max_steps = int(max_steps) if max_steps else None
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps("client"))
        conf.insert_json5("connect/endpoints", need("ACTIVEMAP_ZENOH_CONNECT"))
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("scouting/gossip/enabled", "false")
        self.session = zenoh.open(conf)
        block = zenoh.CongestionControl.BLOCK
        self.publishers = {port: self.session.declare_publisher(key, congestion_control=block)
                           for port, key in self.outputs.items()}
        self.seq = {port: 0 for port in self.outputs}
        self.subscribers = {port: self.session.declare_subscriber(key, zenoh.handlers.FifoChannel(64))
                            for port, key in self.inputs.items()}
        self._start = self.session.declare_subscriber(f"{self.control}/start", zenoh.handlers.RingChannel(1))
        self._stop = self.session.declare_subscriber(f"{self.control}/stop", zenoh.handlers.RingChannel(1))
        self._ready = self.session.declare_publisher(f"{self.control}/ready/{self.node_id}")
        self.terminated = False
        signal.signal(signal.SIGTERM, self._on_signal)
        signal.signal(signal.SIGINT, self._on_signal)

    def _on_signal(self, *_):
        self.terminated = True

    def should_stop(self):
        """True after SIGTERM/SIGINT or a stop broadcast of the run."""
        if self._stop.try_recv() is not None:
            self.terminated = True
        return self.terminated

    def wait_for_start(self, timeout=120.0):
        """The start barrier: announce ready every 200 ms until the launcher says start."""
        deadline = time.monotonic() + timeout
        last = 0.0
        while time.monotonic() < deadline and not self.should_stop():
            if time.monotonic() - last >= 0.2:
                self._ready.put(self.node_id.encode())
                last = time.monotonic()
            if self._start.try_recv() is not None:
                return True
            time.sleep(0.01)
        return False

    def send(self, port, payload):
        """Publishes ``payload`` on output ``port`` with the next sequence number."""
        self.seq[port] += 1
        self.publishers[port].put(payload, attachment=self.seq[port].to_bytes(8, "little"))

    def receive(self, port, poll=0.002):
        """Blocks for the next sample on input ``port``: (sequence number, payload bytes), or None
        when the node is told to stop. An empty payload is the producer's end-of-stream."""
        sub = self.subscribers[port]
        while not self.should_stop():
            sample = sub.try_recv()
            if sample is not None:
                att = sample.attachment
                seq = int.from_bytes(att.to_bytes(), "little") if att is not None else 0
                return seq, sample.payload.to_bytes()
            time.sleep(poll)
        return None

    def close(self):
        """End-of-stream on every output, then a flush delay and the session close."""
        for port in self.outputs:
            self.send(port, b"")
        time.sleep(0.1)
        self.session.close()


class Episode:
    """The lockstep simulator role of BRIDGE.md on top of an :class:`ExternalNode`."""

    def __init__(self, node, sim, max_steps, log=None):
        self.node, self.sim, self.max_steps = node, sim, max_steps
        self.frame_id = 0
        self.steps = 0
        self.log = log

    def _log(self, **record):
        if self.log is not None:
            self.log.write(json.dumps(record) + "\n")
            self.log.flush()

    def _status(self, state, message, step=None):
        self.node.send("episode", codec.encode_episode_status(
            self.frame_id if step is None else step, self.max_steps, state, message))

    def publish(self, state="running", message=""):
        """Renders and publishes frame ``frame_id`` with its true pose and the episode status."""
        rgb, depth = self.sim.render()
        stamp = self.frame_id * STEP_SECONDS
        w, h = self.sim.width, self.sim.height
        self.node.send("rgbd", codec.encode_rgbd(self.frame_id, stamp, self.sim.intrinsics, w, h, rgb, depth))
        translation, rotation = self.sim.true_pose()
        if "true_pose" in self.node.outputs:
            self.node.send("true_pose", codec.encode_true_pose(self.frame_id, stamp, translation, rotation))
        self._status(state, message)
        self._log(event="frame", id=self.frame_id, state=state, translation=list(translation))

    def run(self):
        """Frame 0, then one frame per action until the episode ends. Returns the end reason."""
        self.publish("running", "start")
        while True:
            got = self.node.receive("action")
            if got is None:
                return "stopped"
            _, payload = got
            if not payload:
                self._status("failed", "the action stream closed", self.steps)
                return "action stream closed"
            step, action = codec.decode_action(payload)
            self._log(event="action", step=step, action=action)
            if step != self.frame_id:
                raise RuntimeError(f"lockstep action for step {step} but the last frame was {self.frame_id}")
            if action == "stop":
                self._status("finished", "stop action", self.steps)
                return "stop action"
            collided = self.sim.step(action)
            self.steps += 1
            self.frame_id += 1
            if self.steps >= self.max_steps:
                self.publish("finished", "max_steps reached")
                return "max_steps reached"
            self.publish("running", "collided" if collided else "")


def main():
    node = ExternalNode()
    try:
        config = node.config
        sim = make_simulator(config)
        max_steps = node.max_steps or int(config.get("max_steps", 2000))
        if max_steps < 1:
            raise ValueError("max_steps must be >= 1")
        for port in ("rgbd", "episode"):
            if port not in node.outputs:
                raise ValueError(f"the node needs an output `{port}` (declared: {sorted(node.outputs)})")
        if "action" not in node.inputs:
            raise ValueError(f"the node needs an input `action` (declared: {sorted(node.inputs)})")
        log = open(config["log"], "a", encoding="utf-8") if config.get("log") else None
        if not node.wait_for_start():
            print(f"{node.node_id}: no start from the launcher", file=sys.stderr)
            return 1
        reason = Episode(node, sim, max_steps, log).run()
        print(f"{node.node_id}: episode over: {reason}", file=sys.stderr)
        return 0
    finally:
        node.close()


if __name__ == "__main__":
    sys.exit(main())

"""Shared by the acquisition tests: small relightable models, a frame source on a SimCamera,
and the statistics an averaged capture must follow."""
import math

import numpy as np

from lightstage_physics.rig import Rig
from lightstage_physics.scene_models import ModelSet
from helpers.suite import GraphClient, lightstage_command, start_nodes


def smooth_modelset(shape=(24, 32), n_samples=2, seed=0, top=600.0, dark=True) -> ModelSet:
    """Smooth random single-LED images, levels ~0..`top` (a dark corner near 0 when `dark`,
    so clipping at 0 is exercised), on the paper's 8-site rig at `shape`."""
    rng = np.random.default_rng(seed)
    h, w = shape
    yy, xx = np.meshgrid(np.linspace(0, 1, h), np.linspace(0, 1, w), indexing='ij')
    models = np.empty((n_samples, 4, 8, h, w), np.float32)
    for i in range(n_samples):
        for c in range(4):
            for s in range(8):
                a, b, ph = rng.uniform(0.5, 3, 3)
                field = 0.5 + 0.5 * np.sin(a * 3 * xx + ph) * np.cos(b * 2 * yy)
                level = rng.uniform(0.2, 1.0) * top
                models[i, c, s] = level * field * (xx + yy) / 2 if dark else level * (0.2 + 0.8 * field)
    rig = Rig.paper_default(shape)
    names = [f'banana-fake/s{i}/p00' for i in range(n_samples)]
    return ModelSet(models, np.zeros(n_samples, int), ['banana-fake'], names,
                    np.arange(n_samples), np.arange(n_samples), rig)


def sim_grab(camera, exposure_us, gain_db, log=None):
    """grab(patterns (32, k)) -> k mono16 frames from a SimCamera (the stage without ROS)."""
    def grab(patterns):
        if log is not None:
            log.append(patterns.shape[1])
        return [camera.capture(patterns[:, j], exposure_us, gain_db)
                for j in range(patterns.shape[1])]
    return grab


def averaged_capture_z(captured, model, noise, n_frames, max_level=1023, bit_depth=10):
    """z-scores of averaged captured images against the sim camera's exact frame
    distribution: mean and variance of round(clip(N(model, var))) (`frame_moments`), the
    variance divided by the frames averaged, plus the uniform rounding of the capture folder's
    16-bit storage (1/2^(16-bits) gray levels)."""
    from lightstage_camera.sim_camera import frame_moments
    model = np.asarray(model, np.float64)
    mean, var = frame_moments(model, noise.variance(model), max_level)
    step = 1.0 / (1 << (16 - bit_depth))
    return (np.asarray(captured, np.float64) - mean) / np.sqrt(var / n_frames + step ** 2 / 12)


def gaussian_regime(model, noise, max_level=1023, k=4.0):
    """Pixels whose single frames stay more than k sd from 0 and the maximum: there a frame
    is Gaussian (no clipping), and so is an average of frames."""
    model = np.asarray(model, np.float64)
    sd = np.sqrt(noise.variance(model))
    return (model - k * sd > 0) & (model + k * sd < max_level)


def check_z(z, tail_mask=None, family_alpha: float = 1e-3) -> None:
    """Assert n independent z-scores look standard normal, each check at about
    `family_alpha`: mean within 4.5 / sqrt(n); mean square within 1 +- 4.5 sd(z^2) / sqrt(n)
    (studentized: single frames near 0 are far from Gaussian, the average over many pixels
    is not); max |z| over `tail_mask` (pixels whose frames are Gaussian: near 0 the average of
    a few clipped frames has a long right tail) below the two-sided Bonferroni quantile."""
    from scipy.stats import norm
    z = np.asarray(z, np.float64)
    flat = z.ravel()
    n = flat.size
    assert abs(flat.mean()) < 4.5 / math.sqrt(n), f'bias: mean z {flat.mean():.4f} over {n} pixels'
    z2 = flat * flat
    assert abs(z2.mean() - 1) < 4.5 * z2.std() / math.sqrt(n), \
        f'spread: mean z^2 {z2.mean():.4f} over {n} pixels (sd of z^2 {z2.std():.3f})'
    tail = np.abs(z if tail_mask is None else z[tail_mask]).ravel()
    assert tail.size > 0
    limit = float(norm.isf(family_alpha / (2 * tail.size)))
    assert tail.max() < limit, f'outlier: max |z| {tail.max():.2f} >= {limit:.2f} ({tail.size} px)'


# --------------------------------------------------------------------------- the graph


class StageGraph(GraphClient):
    """The test's own ROS participant: starts nodes, sends action goals, sets parameters
    atomically, counts /illumination messages."""

    def __init__(self, domain_id: int):
        super().__init__(domain_id)
        self.illumination = []
        from lightstage_graph.names import ILLUMINATION_TOPIC
        from lightstage_graph.qos import ILLUMINATION_QOS
        from lightstage_interfaces.msg import IlluminationState
        self.node.create_subscription(IlluminationState, ILLUMINATION_TOPIC, self.illumination.append,
                                      ILLUMINATION_QOS)

    def start(self, supervisor, names, params=None, timeout_s: float = 30.0) -> None:
        """Start registry nodes as processes and wait until they spin (`start_nodes`)."""
        start_nodes(supervisor, self, names, self.domain_id, params, timeout_s)

    def action(self, action_type, name: str, goal, timeout_s: float = 120.0, cancel_when=None):
        """Send a goal; returns (status, result, feedback messages). `cancel_when(feedback)`
        True sends a cancel request (once)."""
        feedback, cancel, handle_box = [], [], []

        def on_feedback(msg):
            feedback.append(msg)
            if cancel_when is not None and not cancel and cancel_when(msg):
                cancel.append(handle_box[0].cancel_goal_async())

        handle = self.send_goal(action_type, name, goal, wait_s=15.0, on_feedback=on_feedback,
                                timeout_s=15.0)
        handle_box.append(handle)
        if not handle.accepted:
            return None, None, feedback
        result = self.result(handle.get_result_async(), timeout_s, f'the result of {name}')
        return result.status, result.result, feedback

    def set_parameters(self, node_name: str, **values):
        """SetParametersAtomically on a node; returns the one SetParametersResult."""
        return self.set_parameters_atomically(node_name, values)


def cli(*args, domain_id: int, timeout: float = 300):
    """Run `lightstage VERB ...` (the installed CLI) in a fresh process."""
    import subprocess
    return subprocess.run(lightstage_command(*args, '--domain-id', str(domain_id)),
                          capture_output=True, text=True, timeout=timeout)

"""The light stage driver node: a managed (lifecycle) node around `stage.LightStage`.

configure  opens the port (or starts the Python firmware simulator for `port:=sim`) and
           identifies the firmware;
activate   arms it: `/lightstage/apply_patterns` is served, `/illumination` is published
           at every trigger, heartbeats keep the firmware watchdog fed;
deactivate switches every LED off; cleanup closes the port; shutdown does both.
With `autostart` (default) the node configures and activates itself, so the graph comes
up without a lifecycle manager. `/diagnostics` reports the link in every state.

A lost link (the port gone, the firmware silent, the node's own simulator exited) is noticed
by the failing heartbeat or command, or at once by the simulator's exit: the state becomes
`link down` (ERROR on `/diagnostics`), requests fail at once with the reason, and a thread
reopens the port (restarting the simulator first for `port:=sim`) every
`reconnect_period_s` until the firmware answers; then every LED is switched off and the
node is armed again.
"""
from __future__ import annotations

import sys
import threading
import time
import traceback

import numpy as np
from builtin_interfaces.msg import Time
from lightstage_graph.diagnostics import ERROR, OK, WARN, DiagnosticsPublisher, Report
from lightstage_graph.exits import describe_exit
from lightstage_graph.limits import requested_gain_db
from lightstage_graph.links import ReaderMatch
from lightstage_graph.names import APPLY_PATTERNS_SERVICE, DRIVER_NODE, ILLUMINATION_TOPIC
from lightstage_graph.params import boolean, declare_parameters, floating, integer, string
from lightstage_graph.qos import ILLUMINATION_QOS
from lightstage_graph.spin import init_node, spin_until_stopped
from lightstage_graph.stamps import ns_to_stamp
from lightstage_interfaces.msg import IlluminationState
from lightstage_interfaces.srv import ApplyPatterns
from rcl_interfaces.msg import SetParametersResult
from rclpy.lifecycle import Node as LifecycleNode
from rclpy.lifecycle import State, TransitionCallbackReturn
from rclpy.qos import qos_profile_services_default
from rclpy.service_introspection import ServiceIntrospectionState

from .errors import DisconnectedError, FirmwareMismatchError, LightStageError, PatternError
from .request_check import check_request, rounding_note
from .sim_backend import backend_from_url, is_sim_url
from .stage import LightStage, Trigger


def _sentence(text: str) -> str:
    """`text` ending in one full stop, to go before another sentence."""
    return text.rstrip('. ') + '.'


ON_CONFIGURE = ' (taken at configure: settable while the driver is unconfigured)'
ON_ACTIVATE = ' (taken at activate: settable while the driver is not active)'

PARAMETERS = {
    'port': ('sim', string('serial port path, usb:SERIAL, or sim / sim://?pwm_bits=8&latency_ms=1 '
                           'to start the Python firmware simulator' + ON_CONFIGURE)),
    'baud': (115200, integer('serial baud rate' + ON_CONFIGURE, 1200, 2_000_000)),
    'timeout_ms': (100, integer('reply timeout per attempt [ms] (FIRE adds its exposure; a sequence '
                                'fails after (retries + 1) x this with no trigger event beyond its '
                                'exposures)' + ON_CONFIGURE, 5, 10_000)),
    'retries': (3, integer('retries after a lost or corrupted reply' + ON_CONFIGURE, 0, 10)),
    'connect_timeout_s': (3.0, floating('time to wait for the firmware at configure [s]' + ON_CONFIGURE,
                                        0.1, 30.0)),
    'default_exposure_us': (30_000, integer('exposure for patterns whose exposure_us is 0 [us]',
                                            1, 10_000_000)),
    'gap_us': (0, integer('dark time between the triggers of a sequence [us]', 0, 1_000_000)),
    'heartbeat_period_s': (0.25, floating('heartbeat period while active [s]' + ON_ACTIVATE,
                                          0.02, 10.0)),
    'watchdog_ms': (1000, integer('firmware watchdog: LEDs off after this much host silence [ms]'
                                  + ON_CONFIGURE, 50, 60_000)),
    'diagnostics_period_s': (1.0, floating('/diagnostics period [s]', 0.1, 60.0, read_only=True)),
    'reconnect_period_s': (1.0, floating('while the link is down: time between attempts to reopen the port '
                                          '(restarting the simulator first for port sim) [s]', 0.1, 60.0)),
    'sites': (8, integer('rig layout: illumination sites the firmware must report' + ON_CONFIGURE,
                         1, 32)),
    'channels': (4, integer('rig layout: LEDs (colour channels) per site the firmware must report'
                            + ON_CONFIGURE, 1, 32)),
    'frame_id': ('lightstage', string('frame id of the rig in IlluminationState headers')),
    'autostart': (True, boolean('configure and activate on start-up', read_only=True)),
    'service_introspection': (True, boolean(
        'publish the ApplyPatterns calls (request and response contents) on '
        '/lightstage/apply_patterns/_service_event, so that recordings hold them', read_only=True)),
}
# the lifecycle states in which a parameter taken at a transition may change: a value set
# at another time would change nothing until that transition, while `ros2 param set` said
# "successful"
SETTABLE_IN = {**{name: ('unconfigured',) for name, (_, d) in PARAMETERS.items()
                  if d.description.endswith(ON_CONFIGURE)},
               **{name: ('unconfigured', 'inactive') for name, (_, d) in PARAMETERS.items()
                  if d.description.endswith(ON_ACTIVATE)}}


def refused_change(name: str, state: str) -> str:
    """Why `name` cannot change in lifecycle state `state` ('' if it can), with what to do."""
    allowed = SETTABLE_IN.get(name)
    if allowed is None or state in allowed:
        return ''
    steps = {'active': 'deactivate, cleanup', 'inactive': 'cleanup'}.get(state, 'cleanup')
    if allowed == ('unconfigured',):
        return (f'{name} is taken when the driver is configured and it is {state}: '
                f'`ros2 lifecycle set /{DRIVER_NODE}` {steps}, set {name}, then configure and activate')
    return (f'{name} is taken when the driver is activated and it is {state}: '
            f'`ros2 lifecycle set /{DRIVER_NODE} deactivate`, set {name}, then activate')


class LightStageDriverNode(LifecycleNode):
    def __init__(self, node_name: str = DRIVER_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        self.p = declare_parameters(self, PARAMETERS)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.stage: LightStage | None = None
        self.backend = None
        self.request_id = 0
        self.sequence = 0
        self.errors = 0
        self.faults = 0
        self.last_error = ''
        self.link_state = 'unconfigured'
        self._illumination_pub = None
        self._illumination_readers: ReaderMatch | None = None
        self._heartbeat_timer = None
        self._active = False
        self.link_down = ''              # why the link is down ('' while it is up)
        self.simulator_restarts = 0
        self._link_guard = threading.Lock()       # link_down and the reconnect thread
        self._reconnect_thread: threading.Thread | None = None
        self._stop_reconnect = threading.Event()
        self.diagnostics = DiagnosticsPublisher(self, 'light stage link', self._link_status,
                                                self.p('diagnostics_period_s'))
        self._service = self.create_service(ApplyPatterns, APPLY_PATTERNS_SERVICE, self._on_apply)
        if self.p('service_introspection'):
            self._service.configure_introspection(self.get_clock(), qos_profile_services_default,
                                                  ServiceIntrospectionState.CONTENTS)

    def _on_set_parameters(self, params) -> SetParametersResult:
        state = self._state_machine.current_state[1]
        reasons = [r for r in (refused_change(p.name, state) for p in params) if r]
        return SetParametersResult(successful=not reasons, reason='; '.join(reasons))

    # ------------------------------------------------------------------ lifecycle
    def autostart(self) -> None:
        """Configure and activate; if configuring fails the node stays up, unconfigured, and
        /diagnostics shows why (configure again once fixed)."""
        if self.trigger_configure() == TransitionCallbackReturn.SUCCESS:
            self.trigger_activate()
        else:
            self.get_logger().error(f'autostart: not configured ({self.last_error}); fix it and '
                                    f'trigger configure + activate, or restart the node')
            self.link_state = 'unconfigured'

    def destroy_node(self) -> None:
        """The stage is released first: LEDs off, port closed, simulator stopped."""
        self._active = False
        self._stop_heartbeat()
        self._release()
        super().destroy_node()

    def on_configure(self, state: State) -> TransitionCallbackReturn:
        port = self.p('port')
        if self.p('heartbeat_period_s') * 1000.0 > self.p('watchdog_ms') / 2:
            self._note_error(f'heartbeat_period_s {self.p("heartbeat_period_s")} is too long for watchdog_ms '
                             f'{self.p("watchdog_ms")}: LEDs left lit would go dark between heartbeats; '
                             f'keep the period at most half the watchdog')
            self.get_logger().error(self.last_error)
            return TransitionCallbackReturn.FAILURE
        try:
            if is_sim_url(port):
                self.backend = backend_from_url(port)
                self.backend.start()
                self.backend.on_exit = self._on_simulator_exit
                device = self.backend.port
                self.get_logger().info(f'started the Python firmware simulator on {device}')
            else:
                device = port
            self.stage = LightStage(device, self.p('baud'), self.p('timeout_ms') / 1000.0, self.p('retries'),
                                    self.p('connect_timeout_s'), watchdog_ms=self.p('watchdog_ms'),
                                    on_watchdog=self._on_watchdog, auto_reopen=False)
            ident = self.stage.connect()
            layout = (self.p('sites'), self.p('channels'))
            if (ident.sites, ident.channels) != layout:
                raise FirmwareMismatchError(
                    f'firmware {ident.name} on {device} drives {ident.sites} sites x {ident.channels} '
                    f'channels, but this rig is configured as {layout[0]} x {layout[1]}: fix the sites/'
                    f'channels parameters or flash the right firmware')
        except (LightStageError, ValueError, RuntimeError) as exc:
            self._note_error(f'configure failed: {exc}')
            self.get_logger().error(self.last_error)
            self._release()
            return TransitionCallbackReturn.FAILURE
        self.link_state = 'connected'
        self.link_down = ''
        self.get_logger().info(
            f'connected to {ident.name} {ident.version_string} on {device}: {ident.led_count} LEDs '
            f'({ident.sites} sites x {ident.channels} channels), pwm_bits {ident.pwm_bits}, exposure '
            f'{ident.min_exposure_us}..{ident.max_exposure_us} us, watchdog {self.p("watchdog_ms")} ms')
        self._illumination_pub = self.create_lifecycle_publisher(IlluminationState, ILLUMINATION_TOPIC,
                                                                 ILLUMINATION_QOS)
        self._illumination_readers = ReaderMatch(self, self._illumination_pub)
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: State) -> TransitionCallbackReturn:
        self._heartbeat_timer = self.create_timer(self.p('heartbeat_period_s'), self._heartbeat)
        self._active = True
        self.link_state = 'armed'
        return super().on_activate(state)

    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        self._active = False
        self._stop_heartbeat()
        self._leds_off('deactivate')
        self.link_state = 'connected'
        return super().on_deactivate(state)

    def on_cleanup(self, state: State) -> TransitionCallbackReturn:
        self._release()
        self.link_state = 'unconfigured'
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: State) -> TransitionCallbackReturn:
        self._active = False
        self._stop_heartbeat()
        self._release()
        self.link_state = 'shut down'
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: State) -> TransitionCallbackReturn:
        self._active = False
        self._stop_heartbeat()
        self._release()
        self.link_state = 'error'
        return TransitionCallbackReturn.SUCCESS

    def _stop_heartbeat(self) -> None:
        if self._heartbeat_timer is not None:
            self.destroy_timer(self._heartbeat_timer)
            self._heartbeat_timer = None

    def _release(self) -> None:
        """LEDs off (best effort), port closed, simulator stopped."""
        if self.backend is not None:
            self.backend.on_exit = None    # stopping it now is no fault
        self._stop_reconnecting()
        if self.stage is not None:
            self.stage.close(all_off=True)
            self.stage = None
        if self.backend is not None:
            self.backend.close()
            self.backend = None
        if self._illumination_pub is not None:
            self.destroy_lifecycle_publisher(self._illumination_pub)
            self._illumination_pub = None
            self._illumination_readers = None

    def _leds_off(self, why: str) -> str:
        """Switch every LED off: '' when done, else why not (logged)."""
        if self.stage is None:
            return ''
        failed = f'the link is down ({self.link_down})' if self.link_down else self.stage.try_all_off()
        if failed:
            self._note_error(f'could not switch LEDs off ({why}): {_sentence(failed)} {self._leds_unknown()}')
            self.get_logger().error(self.last_error)
        return failed

    def _leds_unknown(self) -> str:
        """What is known of the LEDs when the board does not answer."""
        return (f'The board is unreachable, so the state of its LEDs is unknown (the last command may '
                f'have left them lit): a board that still runs switches them off itself once its '
                f'watchdog (watchdog_ms = {self.p("watchdog_ms")}) has heard nothing for that long, and '
                f'the driver switches them off when it reconnects')

    # ------------------------------------------------------------------ lost link
    def _recovery_plan(self) -> str:
        what = 'restarts its firmware simulator and reconnects' if self.backend is not None else \
            f'tries to reopen {self.p("port")}'
        return f'the driver {what} every {self.p("reconnect_period_s"):g} s'

    def _on_simulator_exit(self, code: int | None) -> None:
        # the simulator's reader thread: its process is gone, the pty with it
        how = 'closed its output' if code is None else f'ended ({describe_exit(code)})'
        self._link_lost(f'the firmware simulator process {how}')

    def _link_lost(self, reason: str) -> None:
        """Mark the link down (requests fail at once) and reconnect in the background.
        Called from the executor or the simulator's reader thread."""
        with self._link_guard:
            if self.stage is None or self.link_down:
                return
            self.link_down = reason
            self._note_error(f'link down: {reason}')
            self.get_logger().error(f'{_sentence(self.last_error)} {self._leds_unknown()}; {self._recovery_plan()}')
            self._stop_reconnect.clear()
            self._reconnect_thread = threading.Thread(
                target=self._reconnect, args=(self.stage, self.backend, reason, self.p('reconnect_period_s')),
                daemon=True, name='lightstage-reconnect')
            self._reconnect_thread.start()

    def _reconnect(self, stage: LightStage, backend, reason: str, period_s: float) -> None:
        """Until the firmware answers again: (restart the simulator,) reopen, identify, LEDs off."""
        if stage.link.is_open:
            stage.try_all_off()      # the port still works (a silent firmware): worth one try
        stage.link.close()
        # wait first: a re-plugged board needs a moment, and a simulator that dies at once must
        # not be restarted in a tight loop
        while not self._stop_reconnect.wait(period_s):
            try:
                if backend is not None and not backend.running:
                    backend.restart()
                    self.simulator_restarts += 1
                    self.get_logger().info(f'restarted the firmware simulator (pid {backend.pid})')
                stage.link.ensure_open()
                stage.all_off()      # a known state: dark
            except Exception as exc:  # noqa: BLE001 (this thread must outlive any failure)
                stage.link.close()
                with self._link_guard:
                    if not self._stop_reconnect.is_set():
                        self.link_down = f'{reason}; reconnecting failed: {exc}'
                continue
            with self._link_guard:
                if self._stop_reconnect.is_set():
                    return
                self.link_down = ''
                self.link_state = 'armed' if self._active else 'connected'
            self.get_logger().info(f'link to the stage is back ({stage.link.device}); LEDs switched off')
            return

    def _stop_reconnecting(self) -> None:
        self._stop_reconnect.set()
        thread = self._reconnect_thread
        if thread is not None and thread is not threading.current_thread():
            # at most one attempt in flight: a simulator start and a connect
            thread.join(self.p('connect_timeout_s') + 15.0)
        self._reconnect_thread = None
        self.link_down = ''

    def _note_error(self, message: str) -> None:
        self.errors += 1
        self.last_error = message

    def _on_watchdog(self, t_us: int) -> None:
        self._note_error(f'firmware watchdog switched the LEDs off at firmware t={t_us} us '
                         f'(host was silent too long)')
        self.get_logger().warning(self.last_error)

    # ------------------------------------------------------------------ periodic work
    def _heartbeat(self) -> None:
        if self.stage is None or self.link_down:
            return
        try:
            self.stage.heartbeat()
            self.link_state = 'armed'
        except Exception as exc:  # noqa: BLE001 (a timer callback that raises stops the node)
            if not isinstance(exc, LightStageError):
                self.get_logger().error(f'unexpected error in the heartbeat: {traceback.format_exc()}')
            self.faults += 1
            self._link_lost(f'heartbeat failed: {exc}')

    def _link_status(self) -> Report:
        """The link's /diagnostics status."""
        ident = self.stage.link.identity if self.stage is not None else None
        stats = self.stage.link.stats.as_dict() if self.stage is not None else {}
        state = 'link down' if self.link_down else self.link_state
        healthy = state in ('armed', 'connected')
        if healthy:
            level = OK
        elif state == 'unconfigured' and not self.last_error:
            level = WARN
        else:
            level = ERROR
        if self.link_down:
            message = f'link down: {self.link_down}; {self._recovery_plan()}'
        elif not self.last_error or healthy:
            message = state
        else:
            message = f'{state}: {self.last_error}'
        values = {'state': state, 'port': str(self.p('port')),
                  'device': self.stage.link.device if self.stage else '',
                  'firmware': ident.name if ident else '', 'firmware_version': ident.version_string if ident else '',
                  'pwm_bits': ident.pwm_bits if ident else '', 'triggers': self.sequence,
                  'requests': self.request_id, 'errors': self.errors, 'faults': self.faults,
                  'watchdog_trips': self.stage.watchdog_trips if self.stage else 0,
                  'simulator_pid': (self.backend.pid or '') if self.backend is not None else '',
                  'simulator_restarts': self.simulator_restarts,
                  'last_error': self.last_error,
                  'clock_uncertainty_us': (round(self.stage.clock.uncertainty_s * 1e6, 1)
                                           if self.stage and self.stage.clock.synced else ''),
                  **stats}
        return Report(level, message, values,
                      hardware_id=f'{ident.name} {ident.version_string}' if ident else '')

    # ------------------------------------------------------------------ service
    def _on_apply(self, request: ApplyPatterns.Request, response: ApplyPatterns.Response):
        response.success = False
        if not self._active or self.stage is None:
            response.message = (f'the driver is not active (state {self.link_state}); configure and '
                                f'activate it (or start it with autostart:=true)')
            return response
        if self.link_down:
            response.message = (f'the link to the stage is down ({self.link_down}); nothing was sent; '
                                f'{self._recovery_plan()}: retry when /diagnostics reports "armed"')
            return response
        try:
            ident = self.stage.identity
            intensities, exposures = check_request(request.patterns, self.p('default_exposure_us'),
                                                   ident.min_exposure_us, ident.max_exposure_us)
        except PatternError as exc:
            response.message = f'rejected, nothing was sent: {exc}'
            return response
        except Exception as exc:  # noqa: BLE001 (no request may take the node down)
            response.message = f'rejected, nothing was sent: the request could not be read ({type(exc).__name__}: {exc})'
            return response
        self.request_id += 1
        response.request_id = self.request_id
        published: list[Trigger] = []

        def publish(trigger: Trigger) -> None:
            # as each trigger is reported, so cameras get it while the sequence still runs
            self.sequence += 1
            stamp = self._ros_stamp(trigger)
            response.trigger_stamps.append(stamp)
            response.sequences.append(self.sequence)
            published.append(trigger)
            self._publish_illumination(trigger, request.patterns[trigger.index], stamp, len(request.patterns))

        readers = self._illumination_readers
        if request.trigger and readers is not None:
            readers.wait()   # a camera that just subscribed gets the first trigger too
        try:
            triggers = self.stage.apply(intensities, exposures, trigger=request.trigger, gap_us=self.p('gap_us'),
                                        on_trigger=publish)
        except PatternError as exc:
            response.message = f'rejected, nothing was sent: {exc}'
            return response
        except Exception as exc:  # noqa: BLE001 (no request may take the node down)
            if not isinstance(exc, LightStageError):
                self.get_logger().error(f'unexpected error while applying: {traceback.format_exc()}')
                exc = LightStageError(f'{type(exc).__name__}: {exc}')
            self.faults += 1
            self._note_error(f'apply failed: {exc}')
            self.get_logger().error(self.last_error)
            happened = f'{len(published)} trigger(s) happened and were published'
            # a port that went away takes no ALL_OFF: do not wait for it
            off_failed = str(exc) if isinstance(exc, DisconnectedError) else self._leds_off('fault')
            if not off_failed:
                self.link_state = 'fault'
                response.message = f'{exc} (LEDs switched off; {happened})'
                return response
            self._link_lost(f'apply failed: {exc}')
            response.message = f'{_sentence(str(exc))} {self._leds_unknown()}; {self._recovery_plan()}. {happened}.'
            return response
        self.link_state = 'armed'
        if len(published) != len(triggers):    # a callback missed: should not happen, be explicit
            response.message = f'{len(triggers)} triggers but {len(published)} published'
            return response
        response.success = True
        applied = [t.applied for t in triggers if t.applied is not None]
        response.message = f'{len(request.patterns)} pattern(s) applied' + \
            (f', {len(triggers)} trigger(s)' if request.trigger else ' (no trigger)') + \
            rounding_note(intensities, applied, self.stage.identity.pwm_bits)
        return response

    def _ros_stamp(self, trigger: Trigger) -> Time:
        # host monotonic -> ROS time: shift "now" back by how long ago the trigger was
        now_ns = self.get_clock().now().nanoseconds
        ago_ns = int(round((time.monotonic() - trigger.host_time_s) * 1e9))
        return ns_to_stamp(now_ns - ago_ns)

    def _publish_illumination(self, trigger: Trigger, pattern, stamp: Time, count: int) -> None:
        if self._illumination_pub is None:
            return
        msg = IlluminationState()
        msg.header.stamp = stamp
        msg.header.frame_id = self.p('frame_id')
        msg.sequence = self.sequence
        msg.request_id = self.request_id
        msg.index_in_request = trigger.index
        msg.count_in_request = count
        # what the board applied: the drives rounded to its level steps (0/1 on an on/off board)
        if trigger.applied is not None:
            msg.intensities = np.asarray(trigger.applied, dtype=np.float32)
        else:
            msg.intensities = np.array([(trigger.word >> i) & 1 for i in range(32)], dtype=np.float32)
        msg.exposure_us = trigger.exposure_us
        msg.gain_db = requested_gain_db(pattern.gain_db, pattern.gain_db_set)   # NaN: the camera's
        self._illumination_pub.publish(msg)


def main(argv: list[str] | None = None) -> int:
    init_node(sys.argv if argv is None else argv)
    node = LightStageDriverNode()
    if node.p('autostart'):
        node.autostart()
    return spin_until_stopped(node)


if __name__ == '__main__':
    sys.exit(main())

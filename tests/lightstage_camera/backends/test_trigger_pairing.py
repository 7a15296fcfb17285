"""TriggerPairing: frames go to their own triggers or are reported lost; never shifted."""
import numpy as np

from lightstage_camera.camera_backend import Frame, LostFrame, Trigger
from lightstage_camera.trigger_pairing import GrabbedFrame, TriggerPairing


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def trig(seq):
    return Trigger(stamp_ns=1_000 + seq, sequence=seq, led_intensities=np.zeros(32, np.float32),
                   exposure_us=1000)


def frame(block, value=None, error=''):
    image = None if error else np.full((2, 2), block if value is None else value, np.uint16)
    return GrabbedFrame(block, image, 16, error=error)


def pairing():
    clock = Clock()
    return TriggerPairing(lambda t: 0.5, early_limit_s=0.5, clock=clock), clock


def outcome(results):
    return [(type(r).__name__, r.trigger.sequence, int(r.image[0, 0]) if isinstance(r, Frame) else r.reason)
            for r in results]


def test_frames_pair_in_order_before_or_after_their_trigger_is_announced():
    p, _ = pairing()
    out = p.add_trigger(trig(0)) + p.add_frame(frame(10))
    out += p.add_frame(frame(11)) + p.add_trigger(trig(1))   # frame first (hardware trigger)
    assert outcome(out) == [('Frame', 0, 10), ('Frame', 1, 11)]
    assert out[0].info['block_id'] == 10


def test_a_block_id_gap_loses_exactly_the_skipped_triggers():
    p, _ = pairing()
    out = []
    for seq in range(4):
        out += p.add_trigger(trig(seq))
    out += p.add_frame(frame(0)) + p.add_frame(frame(2)) + p.add_frame(frame(3))
    kinds = outcome(out)
    assert kinds[0] == ('Frame', 0, 0)
    assert kinds[1][0:2] == ('LostFrame', 1) and 'BlockID 1 missing' in kinds[1][2]
    assert kinds[2:] == [('Frame', 2, 2), ('Frame', 3, 3)]
    # a gap seen before the trigger is announced loses that trigger when it comes
    out = p.add_frame(frame(5)) + p.add_trigger(trig(4)) + p.add_trigger(trig(5))
    assert [o[:2] for o in outcome(out)] == [('LostFrame', 4), ('Frame', 5)]
    assert p.lost == 2 and p.paired == 4


def test_a_failed_buffer_loses_its_own_trigger_only():
    p, _ = pairing()
    out = []
    for seq in range(3):
        out += p.add_trigger(trig(seq))
    out += p.add_frame(frame(0)) + p.add_frame(frame(1, error='The buffer was incompletely grabbed.'))
    out += p.add_frame(frame(2))
    kinds = outcome(out)
    assert kinds[0] == ('Frame', 0, 0) and kinds[2] == ('Frame', 2, 2)
    assert kinds[1] == ('LostFrame', 1, 'failed buffer: The buffer was incompletely grabbed.')


def test_a_trigger_without_frame_is_lost_and_a_late_frame_is_never_shifted_onto_the_next():
    p, clock = pairing()
    out = p.add_trigger(trig(0)) + p.add_trigger(trig(1))
    clock.t = 0.6
    out += p.expire()
    assert [o[:2] for o in outcome(out)] == [('LostFrame', 0), ('LostFrame', 1)]
    assert 'no frame within 0.5 s' in out[0].reason and 'out of step' in out[1].reason
    assert p.timeouts == 1
    # trigger 0's frame comes late, while trigger 2 waits: it must not become trigger 2's
    clock.t = 0.7
    out = p.add_trigger(trig(2)) + p.add_frame(frame(0, value=77))
    assert [o[:2] for o in outcome(out)] == [('LostFrame', 2)]
    assert p.unclaimed == 1
    # quiet for one time limit: pairing starts afresh
    clock.t = 1.5
    out = p.add_trigger(trig(3)) + p.add_frame(frame(1, value=33))
    assert outcome(out) == [('Frame', 3, 33)]


def test_unclaimed_frames_expire_and_a_camera_fault_loses_every_waiting_trigger():
    p, clock = pairing()
    p.add_frame(frame(0))
    clock.t = 0.4
    assert p.expire() == [] and p.unclaimed == 0   # its trigger may still be announced
    clock.t = 0.6
    assert p.expire() == [] and p.unclaimed == 1
    p.add_trigger(trig(0))
    p.add_trigger(trig(1))
    lost = p.fail_all('camera fault: unplugged')
    assert [(type(x), x.trigger.sequence, x.reason) for x in lost] == [
        (LostFrame, 0, 'camera fault: unplugged'), (LostFrame, 1, 'camera fault: unplugged')]
    assert p.waiting == 0

"""Make bags/sim_session: a few classifications on the simulated light stage, recorded.

    .venv/bin/python bags/record_sim_session.py            # rewrites bags/sim_session*
    .venv/bin/python bags/record_sim_session.py --out /tmp/x --domain-id 80

1. a small synthetic capture (banana and orange, real and fake, 2 samples x 3 poses each,
   120 px) in a temporary folder;
2. the greedy illumination search for 2 site patterns (8 images) at Sigma3 on it, saved as
   OUT/sim_session_classifier.npz (the artifact a replay needs);
3. the graph as `lightstage up` starts it -- driver on the Python firmware simulator,
   simulated camera (noise seed 7), classifier -- plus the recorder node writing
   OUT/sim_session, all with LOCALHOST discovery in their own domain;
4. one classification per class through /lightstage/classify (8, 4, 8, 4 images), then
   SIGINT to the recorder, which closes the bag; every trigger and image of the four
   classifications must be in it.
"""
from __future__ import annotations

import argparse
import io
import shutil
import sys
import tempfile
import time
from pathlib import Path

from lightstage_graph.ros_env import apply_ros_environment, ros_environment

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent / 'tests')]  # the tests' helpers package
from helpers.recording import bag_results  # noqa: E402  (the tests' bag and ROS helpers)
from helpers.suite import GraphClient, start_nodes, write_params  # noqa: E402

SAMPLES = ['banana-fake/s1/p02', 'banana-real/s0/p01', 'orange-fake/s1/p00', 'orange-real/s0/p02']
RECORDED = ['/illumination', '/camera/image_raw', '/lightstage/result',
            '/lightstage/classify/_service_event', '/lightstage/apply_patterns/_service_event']


def _train(capture: Path, artifact: Path) -> None:
    from lightstage_physics.capture_format import load_capture
    from mux_trainer.greedy import GreedyPatternSelector
    from mux_trainer.search_params import Execution, Rendering, SplitScoring
    modelset = load_capture(capture, downscale_to=120)
    model = GreedyPatternSelector(n_patterns=2, scoring=SplitScoring(n_repeats=40),
                                  rendering=Rendering(noise='sigma3'), seed=0,
                                  execution=Execution(n_jobs=2))
    model.fit(modelset)
    model.to_artifact(provenance={'made_by': 'bags/record_sim_session.py'}).save(artifact)


def _record(capture: Path, artifact: Path, bag: Path, domain_id: int, work: Path) -> list:
    from lightstage_bringup.launcher import NODE_REGISTRY, node_command
    from lightstage_bringup.supervisor import ProcessSpec, Supervisor
    from lightstage_interfaces.srv import Classify

    params = write_params(work / 'params.yaml', {
        'camera': {'capture_dir': str(capture), 'sample': SAMPLES[0], 'seed': 7},
        'classifier': {'artifact_path': str(artifact)},
        'recorder': {'output_dir': str(bag)},
    })
    client = GraphClient(domain_id, 'record_sim_session')
    out = io.StringIO()
    answers = []
    try:
        with Supervisor(stdout=out, stderr=out, sigint_timeout_s=10.0) as supervisor:
            start_nodes(supervisor, client, ['driver', 'camera', 'classifier'], domain_id, params)
            supervisor.start(ProcessSpec('recorder', node_command(NODE_REGISTRY['recorder'].module,
                                                                  'recorder', params),
                                         ros_environment(domain_id)))
            client.spin_until(lambda: all(client.subscribed_by(t, 'recorder') for t in RECORDED), 30.0,
                              lambda: f'the recorder to subscribe:\n{out.getvalue()}')
            time.sleep(1.0)  # let the publishers match the recorder's new subscriptions
            for i, sample in enumerate(SAMPLES):
                (r,) = client.set_parameters('camera', sample=sample)
                if not r.successful:
                    raise RuntimeError(r.reason)
                answer = client.call(Classify, '/lightstage/classify',
                                     Classify.Request(max_images=8 if i % 2 == 0 else 4))
                if not answer.success:
                    raise RuntimeError(answer.message)
                answers.append((sample, answer))
                print(f'{sample}: {answer.label} ({answer.images_used} images)', flush=True)
            client.spin_for(1.0)
        print(''.join(line + '\n' for line in out.getvalue().splitlines()
                      if line.startswith('[recorder]') and '[INFO]' not in line))
    finally:
        client.close()
    return answers


def _check(bag: Path, answers) -> None:
    from lightstage_recording import BagReader, format_info
    from lightstage_interfaces.msg import IlluminationState
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Image
    reader = BagReader(bag)
    info = reader.info(verify=True)
    if not info.complete:
        raise RuntimeError(f'the bag is incomplete: {info.problems}')
    results = bag_results(bag)
    if [r.label for r in results] != [a.label for _, a in answers]:
        raise RuntimeError('the recorded results are not the answers')
    stamps = {}
    for m in reader.messages(['/illumination']):
        s = deserialize_message(m.data, IlluminationState)
        stamps[s.sequence] = (s.header.stamp.sec, s.header.stamp.nanosec)
    images = {(lambda h: (h.stamp.sec, h.stamp.nanosec))(deserialize_message(m.data, Image).header)
              for m in reader.messages(['/camera/image_raw'])}
    for r in results:
        if not all(q in stamps and stamps[q] in images for q in r.sequences):
            raise RuntimeError(f'triggers or images of {list(r.sequences)} are missing from the bag')
    print(format_info(info))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--out', default=str(HERE), help='folder for sim_session/ and its classifier')
    p.add_argument('--domain-id', type=int, default=77)
    args = p.parse_args(argv)
    apply_ros_environment(args.domain_id)
    out = Path(args.out)
    bag, artifact = out / 'sim_session', out / 'sim_session_classifier.npz'
    shutil.rmtree(bag, ignore_errors=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        from lightstage_physics import synth
        capture = synth.generate(work / 'capture', image_size=120, n_samples_per_class=2, n_poses=3,
                                 object_types=('banana', 'orange'), n_jobs=2)
        t0 = time.perf_counter()
        _train(capture, artifact)
        print(f'trained {artifact} in {time.perf_counter() - t0:.0f} s', flush=True)
        answers = _record(capture, artifact, bag, args.domain_id, work)
    _check(bag, answers)
    return 0


if __name__ == '__main__':
    sys.exit(main())

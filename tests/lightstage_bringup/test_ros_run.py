"""What a ROS user does first: `ros2 run PKG EXE --ros-args --params-file` the shipped YAML,
from a shell that did not activate the venv, and `source .venv/setup.bash` for the ament index.

`ros2 run PKG EXE ARGS` runs `<prefix>/lib/PKG/EXE ARGS`; there is no ros2 CLI here, so the
tests run exactly that command line, in an environment holding only PATH, HOME and the
domain id / discovery range the suite gives. The node names are the nodes' own defaults (no
remapping), so the YAML's sections reach them only if those equal the sections' names.
"""
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from helpers.ros import running_nodes
from helpers.suite import REPO, GraphClient, fresh_domain_id

pytestmark = [pytest.mark.ros, pytest.mark.process]

SHIPPED_YAML = REPO / 'src' / 'lightstage_bringup' / 'config' / 'lightstage.yaml'
VENV = Path(sys.prefix)  # the suite runs with the venv's interpreter
PROJECT_PACKAGES = sorted(p.parent.name for p in (REPO / 'src').glob('*/package.xml'))

# node name (= YAML section) -> (package, executable in lib/<package>/)
ROS_RUN = {
    'driver': ('lightstage_driver', 'driver_node'),
    'camera': ('lightstage_camera', 'camera_node'),
    'classifier': ('mux_classifier', 'classifier_node'),
    'acquisition': ('lightstage_camera', 'acquisition_node'),
    'trainer': ('mux_trainer', 'trainer_node'),
    'recorder': ('lightstage_recording', 'recorder'),
    'player': ('lightstage_recording', 'player'),
}


def clean_environment(domain_id: int) -> dict[str, str]:
    """A login shell's environment without the venv: PATH, HOME, and the suite's ROS settings."""
    return {'PATH': '/usr/local/bin:/usr/bin:/bin', 'HOME': os.environ.get('HOME', '/root'),
            'ROS_DOMAIN_ID': str(domain_id), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}


def get_parameters(client: GraphClient, node: str, names: list[str]) -> dict:
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python
    values = client.call(GetParameters, f'/{node}/get_parameters', GetParameters.Request(names=names)).values
    return {n: parameter_value_to_python(v) for n, v in zip(names, values)}


def test_every_node_executable_names_the_venv_interpreter_or_finds_it():
    """No activation needed: each lib/<pkg>/<exe> runs the venv's Python (checked by running it)."""
    for package, executable in ROS_RUN.values():
        exe = VENV / 'lib' / package / executable
        assert exe.is_file() and os.access(exe, os.X_OK), f'{exe} missing: run scripts/bootstrap.sh'
    probe = subprocess.run([str(VENV / 'lib' / 'lightstage_driver' / 'firmware_sim'), '--help'],
                           env=clean_environment(0), capture_output=True, text=True, timeout=60)
    assert probe.returncode == 0 and 'usage:' in probe.stdout, probe.stderr


def test_ros_run_with_the_shipped_yaml_applies_it_and_classifies(stage_capture, stage_artifact_path,
                                                                   tmp_path):
    # the shipped file, with what a user fills in: the stage's capture folder and classifier,
    # and a non-default value per node so that its section can be seen to take effect
    doc = yaml.safe_load(SHIPPED_YAML.read_text())
    filled = {
        'driver': {'frame_id': 'stage_under_test'},
        'camera': {'capture_dir': str(stage_capture), 'sample': 'orange-real/s1/p02', 'seed': 3},
        'classifier': {'artifact_path': str(stage_artifact_path), 'timeout_s': 12.5},
        'acquisition': {'frames_averaged': 4},
        'trainer': {'n_jobs': 1, 'refine_top': 8},
        'recorder': {'output_dir': str(tmp_path / 'bag'), 'topics': ['/lightstage/result']},
        # a harmless topic, so the played bag cannot disturb the classification
        'player': {'bag': str(REPO / 'bags' / 'sim_session'), 'topics': ['/diagnostics'], 'loop': True},
    }
    assert set(filled) == set(ROS_RUN) and set(ROS_RUN) <= set(doc)
    for name, values in filled.items():
        doc[name]['ros__parameters'].update(values)
    params = tmp_path / 'lightstage.yaml'
    params.write_text(yaml.safe_dump(doc))

    domain_id = fresh_domain_id()
    commands = {name: [str(VENV / 'lib' / pkg / exe), '--ros-args', '--params-file', str(params)]
                for name, (pkg, exe) in ROS_RUN.items()}
    with running_nodes(commands, domain_id, timeout_s=90, env=clean_environment(domain_id)) as sup:
        client = GraphClient(domain_id)
        try:
            for name, values in filled.items():
                assert get_parameters(client, name, list(values)) == values, name
            from lightstage_interfaces.srv import Classify
            r = client.call(Classify, '/lightstage/classify', Classify.Request(max_images=4, timeout_s=20.0),
                            timeout_s=40.0)
            assert r.success, r.message
            assert r.label in r.class_names and r.images_used == 4
            assert r.label.startswith('orange'), r.label  # banana vs orange is clearly separable
        finally:
            client.close()
    # started without the project's environment, each node applied it and said so
    output = sup.output.getvalue()
    for name in ROS_RUN:
        assert any(line.startswith(f'[{name}]') and 'ROS environment: ' in line
                   and 'FASTRTPS_DEFAULT_PROFILES_FILE=' in line for line in output.splitlines()), \
            f'{name} did not report the environment it applied:\n{output}'
    assert (tmp_path / 'bag' / 'metadata.yaml').is_file()


def test_sourcing_the_setup_file_makes_every_package_and_executable_visible():
    """`source .venv/setup.bash` in a clean shell; then ament_index_python (what `ros2 pkg`
    uses) lists each project package, in the venv, with the executables `ros2 run` starts."""
    setup = VENV / 'setup.bash'
    assert setup.is_file(), f'{setup} missing: run scripts/bootstrap.sh'
    probe = r'''
import json, os
from ament_index_python.packages import get_package_prefix, get_packages_with_prefixes
found = {}
for package, prefix in get_packages_with_prefixes().items():
    lib = os.path.join(prefix, 'lib', package)
    exes = sorted(f for f in os.listdir(lib) if os.access(os.path.join(lib, f), os.X_OK)) \
        if os.path.isdir(lib) else []
    found[package] = [prefix, exes]
env = {k: os.environ.get(k) for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'FASTRTPS_DEFAULT_PROFILES_FILE')}
print(json.dumps({'packages': found, 'env': env}))
'''
    script = f'source {setup} && python -c "$PROBE" && . {VENV}/share/lightstage_interfaces/local_setup.sh'
    p = subprocess.run(['env', '-i', 'PATH=/usr/bin:/bin', f'HOME={os.environ.get("HOME", "/root")}',
                        f'PROBE={probe}', 'bash', '--norc', '--noprofile', '-c', script],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 0 and not p.stderr, p.stderr
    import json
    result = json.loads(p.stdout)
    packages = result['packages']
    for package in PROJECT_PACKAGES:
        assert package in packages, f'{package} not in the ament index after sourcing {setup}'
        prefix, executables = packages[package]
        assert Path(prefix) == VENV
        shipped = sorted(f.name for f in (REPO / 'src' / package / 'scripts').glob('*'))
        assert executables == shipped, package
    assert result['env']['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert Path(result['env']['FASTRTPS_DEFAULT_PROFILES_FILE']).is_file()

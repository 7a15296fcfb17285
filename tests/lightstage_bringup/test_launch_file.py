"""The launch file for full ROS installs (launch/launch_ros are not installable here, so it
is checked statically), its params YAML, and that setup.py installs both."""
import ast
import py_compile
import runpy

import setuptools
import yaml

from lightstage_bringup import launcher

from helpers.suite import REPO

PKG = REPO / 'src' / 'lightstage_bringup'
LAUNCH = PKG / 'launch' / 'lightstage.launch.py'
CONFIG = PKG / 'config' / 'lightstage.yaml'
SRC = PKG.parent


def _node_calls(tree: ast.AST) -> list[dict]:
    """Keyword arguments of each Node(...) call, and the (name, package, executable) table."""
    calls = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', None) == 'Node':
            calls.append({k.arg: k.value for k in node.keywords})
    return calls


def test_launch_file_compiles_and_defines_generate_launch_description(tmp_path):
    py_compile.compile(str(LAUNCH), cfile=str(tmp_path / 'launch.pyc'), doraise=True)
    tree = ast.parse(LAUNCH.read_text())
    functions = {f.name for f in tree.body if isinstance(f, ast.FunctionDef)}
    assert 'generate_launch_description' in functions
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
    assert {'LaunchDescription', 'Node', 'DeclareLaunchArgument'} <= imported


def test_launch_file_keeps_discovery_on_this_machine():
    tree = ast.parse(LAUNCH.read_text())
    env = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', None) == 'SetEnvironmentVariable':
            name = ast.literal_eval(node.args[0])
            env[name] = ast.unparse(node.args[1])
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == "'LOCALHOST'"
    unset = [ast.literal_eval(n.args[0]) for n in ast.walk(tree) if isinstance(n, ast.Call)
             and getattr(n.func, 'id', None) == 'UnsetEnvironmentVariable']
    assert unset == ['ROS_STATIC_PEERS']
    # the profile lightstage_graph's setup.py installs to share/lightstage_graph/config
    assert "'fastdds_profile.xml'" in env['FASTRTPS_DEFAULT_PROFILES_FILE']


def test_launch_file_starts_the_registry_nodes_with_executables_that_exist():
    tree = ast.parse(LAUNCH.read_text())
    table = next(ast.literal_eval(n.value) for n in ast.walk(tree)
                 if isinstance(n, ast.Assign) and getattr(n.targets[0], 'id', '') == 'nodes')
    optional = next(ast.literal_eval(n.value) for n in ast.walk(tree)
                    if isinstance(n, ast.Assign) and getattr(n.targets[0], 'id', '') == 'optional')
    assert [name for name, _, _ in table] == list(launcher.DEFAULT_NODES)
    for name, package, executable in table + [row[:3] for row in optional]:
        # the executable is installed to lib/<package>/ (ros2 run / launch_ros look there) ...
        assert (SRC / package / 'scripts' / executable).is_file(), (package, executable)
        assert f"'scripts/{executable}'" in (SRC / package / 'setup.py').read_text()
        # ... and runs the module the launcher's registry starts for that name
        assert f'from {launcher.NODE_REGISTRY[name].module} import main' in \
            (SRC / package / 'scripts' / executable).read_text()
    calls = _node_calls(tree)
    assert len(calls) == 2  # the loop's Node(...) and the optional trainer
    for kw in calls:
        assert {'package', 'executable', 'name', 'parameters'} <= set(kw)


def test_params_yaml_has_a_section_per_registry_node():
    doc = yaml.safe_load(CONFIG.read_text())
    for name in launcher.NODE_REGISTRY:
        assert 'ros__parameters' in doc[name], name
    for section in doc.values():
        assert set(section) == {'ros__parameters'}


def test_setup_installs_launch_and_config_into_share(monkeypatch):
    captured = {}
    monkeypatch.setattr(setuptools, 'setup', lambda **kw: captured.update(kw))
    monkeypatch.chdir(PKG)
    runpy.run_path(str(PKG / 'setup.py'))
    data = {dest: files for dest, files in captured['data_files']}
    assert 'launch/lightstage.launch.py' in data['share/lightstage_bringup/launch']
    assert 'config/lightstage.yaml' in data['share/lightstage_bringup/config']
    for files in data.values():
        for f in files:
            assert (PKG / f).is_file(), f


def test_launch_file_records_by_default_to_a_new_bag_under_bag_dir():
    tree = ast.parse(LAUNCH.read_text())
    arguments = {}
    for n in ast.walk(tree):
        if isinstance(n, ast.Call) and getattr(n.func, 'id', None) == 'DeclareLaunchArgument':
            arguments[ast.literal_eval(n.args[0])] = {k.arg: ast.unparse(k.value) for k in n.keywords}
    # as `lightstage up`: the recorder is on unless use_recorder:=false ...
    assert arguments['use_recorder']['default_value'] == "'true'"
    # ... and writes a new bag under bag_dir (default out/bags), named as the launcher names it
    assert arguments['bag_dir']['default_value'] == "os.path.join('out', 'bags')"
    assert launcher.DEFAULT_BAG_DIR.parts == ('out', 'bags')
    extra = next(n.value for n in ast.walk(tree) if isinstance(n, ast.Assign)
                 and getattr(n.targets[0], 'id', '') == 'extra_parameters')
    assert "'output_dir'" in ast.unparse(extra) and "LaunchConfiguration('bag_dir')" in ast.unparse(extra)
    assert 'default_bag_name()' in ast.unparse(extra)

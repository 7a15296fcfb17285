"""The `lightstage` command: one entry point, verbs owned by the packages that implement them.

Each verb maps to a plain function `main(argv: list[str]) -> int` in the package that owns
the work, imported only when the verb is used so that `lightstage --help` stays fast and a
verb's heavy dependencies (rclpy, scikit-learn) load only when needed.
"""
from __future__ import annotations

import argparse
import importlib
import sys

# verb -> (module, function, one-line help)
VERBS: dict[str, tuple[str, str, str]] = {
    'demo': ('lightstage_bringup.demo', 'main',
             'the whole method on the simulated light stage: synthesise, train, classify on the stage'),
    'up': ('lightstage_bringup.launcher', 'main',
           'start project nodes as separate processes, wait until discoverable, forward logs; '
           'records the graph to out/bags/ unless --no-record'),
    'classify': ('lightstage_bringup.classify_cli', 'main',
                 'classify the sample on the stage through /lightstage/classify'),
    'web': ('lightstage_bringup.web_cli', 'main',
            "the operator's page in a browser beside a running graph (127.0.0.1:8088)"),
    'view': ('lightstage_bringup.view_cli', 'main',
             'serve the graph live to Foxglove / Lichtblick (Foxglove WebSocket, 127.0.0.1:8765)'),
    'record': ('lightstage_recording.bag_cli', 'record_main',
               'record every topic and service call of the graph into an MCAP bag'),
    'play': ('lightstage_recording.bag_cli', 'play_main',
             'play a bag into the graph with its recorded QoS and timing'),
    'bag': ('lightstage_recording.bag_cli', 'bag_main',
            'bag info (summary like `ros2 bag info`) / bag recover (complete copy of a damaged bag) / '
            'bag export (a copy rosbags and mcap_ros2 read)'),
    'synth': ('lightstage_physics.synth_cli', 'main',
              'write the synthetic light-stage dataset (a capture folder)'),
    'capture': ('lightstage_bringup.acquisition_cli', 'capture_main',
                'capture relightable models of the sample on the stage into a capture folder'),
    'calibrate': ('lightstage_bringup.acquisition_cli', 'calibrate_main',
                  'characterize the camera noise on the stage, write a noise file and plot'),
    'train': ('mux_trainer.cli', 'train_main',
              'learn illumination patterns and a classifier from a capture folder'),
    'eval': ('mux_trainer.cli', 'eval_main',
             'evaluate naive, SNR-optimal and greedy illumination on a capture folder'),
}


def _parser() -> argparse.ArgumentParser:
    width = max(len(v) for v in VERBS)
    lines = [f'  {verb:<{width}}  {help_}' for verb, (_, _, help_) in VERBS.items()]
    return argparse.ArgumentParser(
        prog='lightstage',
        description='Multiplexed-illumination light stage: simulate, train, classify.',
        epilog='verbs:\n' + '\n'.join(lines) + '\n\n`lightstage VERB --help` for the options of a verb.',
        formatter_class=argparse.RawDescriptionHelpFormatter)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = _parser()
    if not argv or argv[0] in ('-h', '--help'):
        parser.print_help()
        return 0 if argv else 2
    verb, rest = argv[0], argv[1:]
    if verb not in VERBS:
        parser.error(f'unknown verb {verb!r}; choose one of: {", ".join(VERBS)}')
    module, function, _ = VERBS[verb]
    entry = getattr(importlib.import_module(module), function)
    try:
        return int(entry(rest) or 0)
    except KeyboardInterrupt:  # a verb that has nothing to clean up on Ctrl-C: one line, not a traceback
        print(f'lightstage {verb}: interrupted (Ctrl-C)', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())

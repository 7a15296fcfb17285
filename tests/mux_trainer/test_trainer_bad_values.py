"""`train --out` over a file that is not an artifact, noise
specs and files out of range, --seed and --repeats bounds, Dask addresses refused at once.
Each refused before any work, naming the option or key."""
import pytest
import yaml
from lightstage_physics.noise import NoiseModel, load_noise_file, save_noise_file
from lightstage_physics.errors import NoiseFileError

from mux_trainer.cli import eval_main, train_main
from mux_trainer.cluster import ClusterUnavailable, DaskCluster
from mux_trainer.data import resolve_noise

from helpers.trainer import TINY


def _refused(main, argv, capsys=None):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    return str(exc.value.code)


# ---------------------------------------------------------------- Bad 4: train --out
def test_train_out_over_a_file_that_is_not_an_artifact_is_refused(capture, no_work):
    rig = capture / 'rig.yaml'
    before = rig.read_bytes()
    message = _refused(train_main, [str(capture), '--out', str(rig), '--method', 'naive', *TINY])
    assert f'{rig} exists and is not a trained artifact' in message and '--force' in message
    assert rig.read_bytes() == before


def test_train_out_replaces_an_artifact_and_with_force_anything(capture, tmp_path):
    out = tmp_path / 'a.npz'
    args = [str(capture), '--method', 'naive', '--repeats', '4', '--quiet', *TINY]
    assert train_main([*args, '--out', str(out)]) == 0
    assert train_main([*args, '--out', str(out)]) == 0   # retraining replaces an artifact
    notes = tmp_path / 'notes.txt'
    notes.write_text('mine')
    assert train_main([*args, '--out', str(notes), '--force']) == 0
    assert notes.read_bytes()[:2] == b'PK'


# ---------------------------------------------------------------- --seed, --repeats
@pytest.mark.parametrize('argv, message', [
    (['--seed', '-1'], '--seed: seed must be 0 .. 4294967295 (a numpy seed), got -1'),
    (['--seed', str(2**32)], '--seed: seed must be 0 .. 4294967295'),
    (['--repeats', '100000000'], '--repeats: repeats (random splits per candidate) must be '
                                 '1 .. 10000, got 100000000; the search time grows in proportion: '
                                 '100000000 would take about 2.5e+05 x'),
])
def test_seed_and_repeats_out_of_range_are_refused_naming_the_option(capture, no_work, tmp_path,
                                                                     argv, message):
    assert message in _refused(train_main, [str(capture), '--out', str(tmp_path / 'a.npz'),
                                            *argv, *TINY])
    assert message in _refused(eval_main, [str(capture), *argv, *TINY])


# ---------------------------------------------------------------- noise specs and files
@pytest.fixture
def noise_file(tmp_path):
    return save_noise_file(tmp_path / 'noise.yaml', NoiseModel(0.7, 66.0, 15.0, 30.0))


@pytest.mark.parametrize('setting, message', [
    ('@400:22.5', "the gain (GAIN_DB, before the colon) = 400.0 dB is out of range: give 0 .. 48 dB"),
    ('@1e308:1e308', 'the gain (GAIN_DB, before the colon) = 1e+308 dB is out of range'),
    ('@17.5:-5', 'the exposure (EXPOSURE_MS, after the colon) = -5.0 ms is out of range: give '
                 '0.001 .. 10000 ms'),
    ('@17.5', 'after the @ give GAIN_DB:EXPOSURE_MS, two numbers'),
    ('@a:b', 'after the @ give GAIN_DB:EXPOSURE_MS, two numbers'),
])
def test_noise_file_settings_out_of_range_name_gain_or_exposure(noise_file, setting, message):
    with pytest.raises(ValueError, match=None) as exc:
        resolve_noise(f'{noise_file}{setting}')
    assert message in str(exc.value)


def test_a_good_noise_file_setting_generalizes(noise_file):
    name, model = resolve_noise(f'{noise_file}@17.5:22.5')
    assert model.gain_db == 17.5 and model.exposure_ms == 22.5


@pytest.mark.parametrize('change, message', [
    (lambda m: m.update(sigma_r2=1e300), 'noise_model.sigma_r2 = 1e+300 is out of range'),
    (lambda m: m.update(gain_db='loud'), "noise_model.gain_db must be a number, got 'loud'"),
    (lambda m: m.update(gain_db=1e6), 'noise_model.gain_db = 1000000.0 dB is out of range'),
    (lambda m: m.update(exposure_ms=0), 'noise_model.exposure_ms = 0.0 ms is out of range'),
    (lambda m: m.pop('sigma_p2'), 'noise_model needs sigma_p2, sigma_r2, gain_db, exposure_ms '
                                  '(and may give max_level); missing sigma_p2'),
    (lambda m: m.update(sigmap2=1), 'unknown sigmap2'),
    (lambda m: m.update(max_level=-1), 'noise_model.max_level must be a whole number 1 .. 65535'),
])
def test_noise_files_with_bad_values_name_the_key(noise_file, change, message):
    doc = yaml.safe_load(noise_file.read_text())
    change(doc['noise_model'])
    noise_file.write_text(yaml.safe_dump(doc))
    with pytest.raises(NoiseFileError) as exc:
        load_noise_file(noise_file)
    assert str(noise_file) in str(exc.value) and message in str(exc.value)


def test_a_noise_file_without_noise_model_says_so(noise_file):
    doc = yaml.safe_load(noise_file.read_text())
    del doc['noise_model']
    noise_file.write_text(yaml.safe_dump(doc))
    with pytest.raises(NoiseFileError, match='it has no noise_model mapping'):
        load_noise_file(noise_file)


# ---------------------------------------------------------------- Dask addresses
def test_a_dask_address_that_is_not_one_is_refused_without_a_del_warning(capfd):
    with pytest.raises(ClusterUnavailable, match="'not a url' is not a Dask scheduler address"):
        DaskCluster('not a url', 30.0)
    import gc
    gc.collect()
    assert 'Exception ignored' not in capfd.readouterr().err


def test_a_port_that_refuses_is_reported_at_once_not_after_the_timeout(monkeypatch):
    """The refusal is known from the first connect: no Client (which waits its whole
    timeout, 30 s, retrying) is made."""
    import distributed

    def no_client(*_a, **_k):
        raise AssertionError('a Client was made for a port that refuses connections')
    monkeypatch.setattr(distributed, 'Client', no_client)
    with pytest.raises(ClusterUnavailable, match='refused the connection: nothing listens on port 1'):
        DaskCluster('tcp://127.0.0.1:1', 30.0)

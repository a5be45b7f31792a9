"""
The mcap writer internals the record packer uses (det_sim_ros.io.log.mcap_internals).

They are present in the installed mcap, and a change to them is reported loudly, naming the
mcap version.
"""

from det_sim_ros.io.log import mcap_internals
import pytest


def test_the_installed_mcap_has_the_internals_the_packer_uses():
    mcap_internals.check()   # raises McapInternalsChanged, naming the version, if not


def test_a_changed_mcap_is_reported_with_its_version(monkeypatch):
    """
    Check that a changed mcap writer is reported with its version.

    An mcap whose writer renamed a private (planted here) makes check() fail with the
    version and the missing name, and attach() give None (the add_message path).
    """
    from mcap import writer as mcap_writer

    class Renamed(mcap_writer.Writer):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self._Writer__statistics_v2 = self.__dict__.pop('_Writer__statistics')
    monkeypatch.setattr(mcap_writer, 'Writer', Renamed)
    with pytest.raises(mcap_internals.McapInternalsChanged) as failure:
        mcap_internals.check()
    message = str(failure.value)
    assert f'mcap {mcap_internals.mcap_version()}' in message
    assert '_Writer__statistics missing' in message
    import io
    assert mcap_internals.attach(Renamed(io.BytesIO())) is None


def test_without_the_internals_the_recorder_writes_the_same_file(tmp_path, monkeypatch):
    """
    Check that without the internals the recorder writes the same file.

    When attach() finds no internals, the recorder writes through add_message: the same bytes
    as with the packer.
    """
    import time as time_module
    from det_sim_ros.io.contract import encode_joint_state, TOPIC_TYPES
    from det_sim_ros.io.log import Recorder
    monkeypatch.setattr(time_module, 'time_ns', lambda: 1234)   # the wall start in the metadata

    def write(path):
        with Recorder(path, None, chunk_size=4096, flush_period_s=1e9) as recorder:
            for k in range(300):
                data = [encode_joint_state(['det0'], [float(k)], stamp_ns=k)] * 2
                recorder.record_sample(k * 1000, ['deflection', 'charge'], data, TOPIC_TYPES)
        return open(path, 'rb').read()
    packed = write(tmp_path / 'packed.mcap')
    monkeypatch.setattr(mcap_internals, 'attach', lambda writer: None)
    assert write(tmp_path / 'plain.mcap') == packed

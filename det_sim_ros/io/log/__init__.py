"""
MCAP run logs in the rosbag2 conventions, and a reader that also recovers unfinished files.

Writing (:class:`Recorder`) follows what ``ros2 bag record`` (Jazzy, mcap storage plugin) writes,
so a log opens in Foxglove, ``ros2 bag info|play`` and any rosbag2/MCAP reader:

- header profile ``ros2``; one channel per topic, message encoding ``cdr``
  (:mod:`det_sim_ros.io.cdr`, 4-byte encapsulation header included), channel metadata
  ``offered_qos_profiles`` in the Jazzy
  (metadata version 9) YAML form;
- one schema per type, named ``pkg/msg/Type``, encoding ``ros2msg``: the type's ``.msg`` text
  followed by each dependency (recursively, once) after a line of 80 ``=`` and ``MSG: pkg/Type``;
- ``log_time = publish_time = sim time`` in ns, never decreasing (a smaller time is clamped and
  counted);
- the run is self-describing: an attachment ``scene.yaml`` and a metadata record ``det_sim_ros``
  (package version, scene YAML, stepper, wall start time) at the start of every file, and a
  metadata record ``det_sim_ros.end`` with the counters when the file is closed.

Crash safety. The writer keeps the chunk in progress in memory, so whatever was recorded since
the last flush is not in the file: a SIGKILL loses it. The writer is flushed every
``flush_sim_s`` of log (sim) time (0.05 s) and every ``flush_period_s`` of wall time (0.1 s),
whichever comes first: a SIGKILL loses at most ~50 ms of sim time, in real-time and free-run
mode alike (with ``background=True``, the writer thread's queue too: at most ``max_queue``
items more, which the recording thread writes itself when the writer falls behind; why both
periods: docs/logging.md). Every
flush is one write: the new records followed by a provisional end (DataEnd, a Footer without
summary, the closing magic), written where the next flush continues. So a killed file is a
valid MCAP up to its last flush, which mcap's reader and rosbags open without a manual step
(they scan a file that has no summary); only the index and the ``det_sim_ros.end`` counters
are missing (:func:`recover` adds the index). A file torn anyway (power loss, a kill inside
that one write) is repaired by :func:`recover_unfinished`, which the node runs on its log
directory at start. :meth:`Recorder.close` (the node's shutdown path on SIGINT/SIGTERM, and
``atexit``) finishes and indexes the file. ``max_total_mb``/``max_files`` bound the log
directory: when a file is opened (start, split, reset) or flushed, the oldest files of this
recorder's name pattern are deleted until the rest fits (never the file being written). A
logging fault (disk full, unwritable path, ...) never raises into the caller: it stops recording,
and :attr:`Recorder.fault` says why.

Reading (:class:`LogReader`) streams records in file order and stops quietly at the end of the
readable data, so a file cut by a crash gives every message of every complete chunk.

This package is the one place that reads and writes MCAP; its ``__init__`` is the public face.
Its modules, by job:

- :mod:`.recorder`: the run's order, counters and faults (:class:`Recorder`), with
  :mod:`.rotation` (file names, splits, the bounded directory), :mod:`.flush_policy` (when to
  flush), :mod:`.write_modes` and :mod:`.writer_thread` (writing now or from the writer thread);
- :mod:`.file`: one file in the rosbag2 conventions, written by :mod:`.writer` (the MCAP
  writer on mcap's public record classes, the bytes of ``mcap.writer.Writer``) and
  :mod:`.packing` (Message records packed into its open chunk, runs of samples in C);
- :mod:`.reader`: reading, finished or not, and :func:`recover`;
- :mod:`.runs`: which files are one run (:func:`log_runs`: a split or reset run stays one);
- :mod:`.format`: the bytes the package scans itself and the provisional end;
  :mod:`.compression`: the chunk compressions (one map); :mod:`.tail_stream`: the output file,
  a complete MCAP between flushes; :mod:`.sniff`: MCAP or not, finished or torn.

The messages' CDR is :mod:`det_sim_ros.io.cdr`'s, their ``.msg`` schemas and QoS metadata
:mod:`det_sim_ros.io.schemas`'.
"""

from __future__ import annotations

from .file import logged_scene
from .format import END_METADATA_NAME, LIBRARY, METADATA_NAME, SCENE_ATTACHMENT
from .reader import log_files, LogMessage, LogReader, recover, recover_unfinished
from .recorder import Recorder
from .runs import log_runs, LogRun, LogRuns
from .sniff import file_kind, is_torn
from ..cdr import deserialize, message_class, serialize
from ..schemas import DELIMITER, message_definition, qos_profiles_yaml, type_name_of

__all__ = ['Recorder', 'LogReader', 'LogMessage', 'message_definition', 'qos_profiles_yaml',
           'type_name_of', 'serialize', 'deserialize', 'recover', 'recover_unfinished',
           'is_torn', 'log_files', 'LIBRARY', 'METADATA_NAME', 'END_METADATA_NAME',
           'SCENE_ATTACHMENT', 'DELIMITER', 'message_class', 'file_kind', 'logged_scene',
           'log_runs', 'LogRun', 'LogRuns']

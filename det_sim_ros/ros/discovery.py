"""
How sim_node announces itself to DDS, so readers and nodes that start after it find it at once.

A Fast DDS participant announces itself 5 times 0.1 s apart when it is created, then every 3 s.
A participant created after that first burst (a subscriber or controller process started a
moment after the node, or slower to import) hears nothing from the node until its next
announcement: it learns of the node up to 3 s late and misses those seconds of samples. A
newcomer's own announcements do not always make up for it: the running participant answers
the first one it hears, and when that answer is lost the newcomer waits for the next periodic
announcement (that is also how long a second node of one name would need to notice the first,
det_sim_ros.ros.name_check). How late, with and without these announcements: docs/real_time.md
(bench/first_sample_race.py). The node
cannot know that a reader is coming, so :func:`announce_early` makes its participant announce
itself every 0.1 s for its first ``ANNOUNCE_S`` seconds and every ``REANNOUNCE_S`` after that,
for as long as it runs: a Fast DDS XML profile for this process only, used when the user has
given no profile of their own (``FASTRTPS_DEFAULT_PROFILES_FILE``,
``FASTDDS_DEFAULT_PROFILES_FILE`` or ``DEFAULT_FASTRTPS_PROFILES.xml`` in the working
directory) and the RMW is Fast DDS.
"""

from __future__ import annotations

import contextlib
import os
import tempfile

__all__ = ['ANNOUNCE_S', 'announce_early', 'PROFILE', 'REANNOUNCE_S']

ANNOUNCE_S = 2.0           # s of announcements every 0.1 s after the participant is created
ANNOUNCE_PERIOD_NS = 100_000_000
# s between two announcements after that (Fast DDS: 3 s): a newcomer whose own announcement
# went unanswered waits at most this long (docs/real_time.md, 'The start of a run'); each is one
# small DATA(p) message to each peer
REANNOUNCE_S = 0.25
PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <participant profile_name="det_sim_early_announcements" is_default_profile="true">
    <rtps><builtin><discovery_config>
      <leaseAnnouncement><sec>0</sec><nanosec>{reannounce_ns}</nanosec></leaseAnnouncement>
      <initialAnnouncements>
        <count>{count}</count>
        <period><sec>0</sec><nanosec>{period_ns}</nanosec></period>
      </initialAnnouncements>
    </discovery_config></builtin></rtps>
  </participant>
</profiles>
"""
_PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')


@contextlib.contextmanager
def announce_early(environ=os.environ):
    """
    Within the block, a participant created in this process announces itself early and often.

    Yields True if the profile is in force, False if the user's own DDS setup is left alone.
    """
    if (any(environ.get(name) for name in _PROFILE_VARIABLES)
            or os.path.exists('DEFAULT_FASTRTPS_PROFILES.xml')
            or environ.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp') != 'rmw_fastrtps_cpp'):
        yield False
        return
    fd, path = tempfile.mkstemp(prefix='det_sim_dds_', suffix='.xml')
    with os.fdopen(fd, 'w', encoding='utf-8') as stream:
        stream.write(PROFILE.format(count=int(ANNOUNCE_S * 1e9 / ANNOUNCE_PERIOD_NS),
                                    period_ns=ANNOUNCE_PERIOD_NS,
                                    reannounce_ns=int(REANNOUNCE_S * 1e9)))
    environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = path
    try:
        yield True
    finally:
        environ.pop('FASTRTPS_DEFAULT_PROFILES_FILE', None)
        os.unlink(path)

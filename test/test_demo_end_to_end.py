"""`face-tracking demo` end to end, small: every step runs and the results are the right ones.

The demo chains the commands as a user would (synth, learn from stereo images, train-expressions,
track, enroll, replay of both recognisers, plot, overlay), so a change that breaks how they fit
together (an option one step passes to another, two nodes reading one topic) fails here even
when each command's own tests pass.
"""

from __future__ import annotations

import json

from face_tracking_ros.cli.main import main
from face_tracking_ros.io.bags import read_messages

MAX_ROTATION_MAE_DEG = 5.0  # per axis; the 3-subject run: 0.1-3.6 deg


def test_the_demo_tracks_learns_and_recognises_who_is_who(tmp_path):
    out = tmp_path / 'demo'
    assert main(['demo', '--out', str(out), '--subjects', '3']) == 0
    reports = sorted((out / 'tracked').glob('*_seq_0?.json'))
    assert [report.stem for report in reports] == [
        'stranger_subject_00_seq_00',
        *(f'test_subject_{s:02d}_seq_{q:02d}' for s in (0, 1) for q in (0, 1)),
    ]
    for report in reports:
        figures = json.loads(report.read_text())
        assert figures['tracked'] == figures['frames'] > 0, report.name
        if report.name.startswith('test_'):  # an enrolled subject (the stranger: unknown size)
            assert max(figures['rotation_mae_deg']) < MAX_ROTATION_MAE_DEG, report.name
    identities = {
        events.name: [m.msg.identity for m in read_messages(events, ['face/identity'])]
        for events in (out / 'events').iterdir()
    }
    assert identities == {
        'test_subject_00_seq_01': ['subject_00'],
        'test_subject_01_seq_01': ['subject_01'],
        'stranger_subject_00_seq_00': ['unknown'],
    }
    expressions = read_messages(out / 'events' / 'test_subject_01_seq_01', ['face/expression'])
    assert len(list(expressions)) >= 2  # an onset and its offset at least
    assert (out / 'tracking.png').stat().st_size > 0 and (out / 'tracking.mp4').stat().st_size > 0

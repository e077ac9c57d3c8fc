"""
A 3-second soak of sim_node (endurance; ``sm_ros.bench.soak``).

The same processes as ``python -m sm_ros.bench.soak --seconds 60`` (node, driver with 1,000 force
messages/s, parameter changes at 50 Hz and grab/release, two cloud subscribers), for 3
measured seconds and with a 27,000-point box instead of 100,000 (a 2-core CI machine runs
all five processes). Asserted: no process crashed, the state stayed finite, resident memory
grew by less than ``RSS_GROWTH_MB``, every parameter change the node accepted was applied
(and the out-of-range ones were refused), bad messages were refused, and both subscribers
received clouds holding every particle.
"""

import json

import pytest

pytest.importorskip('rclpy', reason='ROS 2 wheels not installed (pip install -e .[ros])')

from conftest import spare_domain  # noqa: E402
from sm_ros.bench import soak  # noqa: E402

RSS_GROWTH_MB = 64.0
POINTS = 27_000


def test_three_second_soak(tmp_path, warm):
    out = tmp_path / 'soak.json'
    domain = spare_domain()
    # five processes on a loaded 2-core CI machine cannot hold 60 Hz: the rate is the
    # benchmark's business (--max-dropped 0.01 by default), not this test's
    rc = soak.main(['--seconds', '3', '--points', str(POINTS), '--lead', '1',
                    '--domain-id', str(domain), '--json', str(out), '--max-dropped', '1'])
    fig = json.loads(out.read_text())
    assert not fig['crashed'], fig['crashed']
    assert rc == 0
    assert fig['state_finite']
    assert fig['ticks'] > 0 and fig['points'] == soak.box_side(POINTS) ** 3
    assert fig['rss_growth_mb'] < RSS_GROWTH_MB, fig['rss_growth_mb']
    # parameters: sent at 50 Hz, every tenth out of range
    driver = fig['driver']
    assert driver['params_accepted'] > 50 and driver['params_refused'] > 5
    assert not driver['params_unexpected']
    assert fig['every_accepted_parameter_applied']     # node side, and the driver's answers
    assert fig['params_applied'] + fig['params_superseded'] == fig['params_accepted']
    assert all(ok for _, ok in driver['final_values_match'])
    # forces arrive (some may be dropped by the subscription's depth-10 history: a newer
    # wrench replaces an older one anyway) and the bad ones are refused
    assert fig['received'].get('force', 0) > 100, fig['received']
    assert fig['refused'].get('force', 0) > 0
    for sub in fig['subscribers']:
        assert sub['received'] > 10 and sub['bad_size'] == 0 and sub['non_finite'] == 0


def test_dropped_ticks_fail_the_soak():
    fig = {'crashed': {}, 'state_finite': True, 'every_accepted_parameter_applied': True,
           'ticks_expected': 3600, 'dropped_ticks': 486, 'rate_hz_achieved': 51.9,
           'rate_hz_target': 60.0}
    ok, reasons = soak.verdict(fig, 0.01)
    assert not ok and reasons == ['486 of 3600 ticks dropped (13.5 % > 1 %): 51.9 of 60 Hz '
                                  'held']
    assert soak.verdict(dict(fig, dropped_ticks=36), 0.01) == (True, [])
    assert soak.verdict(dict(fig, dropped_ticks=37), 0.01)[0] is False
    assert soak.verdict(fig, 1.0) == (True, [])
    assert soak.verdict(dict(fig, state_finite=False, dropped_ticks=0), 0.01) == \
        (False, ['the state went non-finite'])

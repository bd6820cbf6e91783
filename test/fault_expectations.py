"""What each fault of the matrix must give, written by the tests, not read from the
procedure's table (positioning_cell.procedures.fault_trials.FAULTS): so a wrong expectation in
the procedure is caught. Used by the live matrix (test_faults.py) and the same trials in
process (test_fault_trials.py)."""

from __future__ import annotations

#: Fault → (result codes accepted, words the reason must contain), as the issues and the
#: docs state them; None: the trial reports no code (a flood: every call answered).
EXPECTED: dict[str, tuple[set[str], str] | None] = {
    'foreign trajectory': ({'foreign_sender'}, 'sent by /fault_matrix'),
    'encoder NaN': ({'aborted_fault', 'aborted_encoder'}, 'leg2_length'),
    'encoder frozen': ({'aborted_encoder'}, 'encoder of leg2_length frozen'),
    'axis stuck': ({'aborted_fault'}, 'leg2_length'),
    'drives off': ({'aborted_drives_off'}, 'drives disabled during the move'),
    'driver killed': ({'aborted_driver_lost'}, 'leg driver not responding'),
    'tracker killed': ({'aborted_tracker_lost'}, 'laser tracker not responding'),
    'tracker occluded': ({'aborted_tracker_lost'}, 'laser tracker not responding'),
    'tracker outliers': ({'success', 'aborted_tracker_inconsistent', 'aborted_tracker_lost',
                          'out_of_tolerance'}, ''),
    'encoder noise burst': ({'success'}, 'settled within tolerance'),
    # the encoders' watch names the axis; the tracker's, whichever sees it first, the measure
    'uncommanded motion': ({'uncommanded_motion'}, 'uncommanded motion at standstill: '),
    'spoofed encoders': ({'second_publisher'},
                         'second publisher on /legs/joint_states: /fault_matrix'),
    'spoofed tracker': ({'second_publisher'},
                        'second publisher on /metrology/pose: /fault_matrix'),
    'positioner killed': ({'commander_silent'}, 'commander /positioner silent'),
    'flood of calls': None,
}

#: The faults only a live cell can be given (DDS messages and services).
LIVE_ONLY = ('spoofed encoders', 'spoofed tracker', 'flood of calls')
#: The faults the instant cell takes in process, with their expectation.
IN_PROCESS: dict[str, tuple[set[str], str]] = {
    name: expected for name, expected in EXPECTED.items()
    if expected is not None and name not in LIVE_ONLY}

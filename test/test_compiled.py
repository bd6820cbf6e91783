"""The compilation helpers: one array layout for every kernel call, and the CPUs to run on."""

from __future__ import annotations

import os

import numpy as np

from positioning_cell.core.compiled import available_cpus, kernel_array


def test_kernel_array_passes_plain_arrays_through_and_copies_the_rest() -> None:
    plain = np.zeros((4, 3))
    assert kernel_array(plain) is plain
    read_only = np.zeros((4, 3))
    read_only.setflags(write=False)
    for value in (read_only, np.zeros((3, 4)).T, np.zeros((4, 6))[:, ::2], [[1, 2, 3]]):
        out = kernel_array(value)
        assert out.flags.c_contiguous and out.flags.writeable and out.dtype == np.float64
        np.testing.assert_array_equal(out, np.asarray(value, dtype=float))
    assert kernel_array([1, 2], np.int64).dtype == np.int64


def test_available_cpus_is_the_affinity_mask() -> None:
    assert available_cpus() == len(os.sched_getaffinity(0)) >= 1

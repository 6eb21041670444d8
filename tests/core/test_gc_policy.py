"""The desktop app's garbage-collection policy (core/gc_policy.py): full collections only while idle."""

from __future__ import annotations

import gc

from citylod.core.gc_policy import GcPolicy


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_full_collections_wait_for_an_idle_view() -> None:
    before = gc.get_threshold()
    clock = _Clock()
    policy = GcPolicy(idle_s=1.0, every_s=10.0, clock=clock)
    policy.install()
    try:
        assert gc.get_threshold()[2] > 10**8 and gc.get_freeze_count() > 0
        # Busy (camera moving or tiles loading) however long: never.
        for _ in range(50):
            clock.t += 1.0
            assert not policy.tick(busy=True)
        # Idle, but not yet idle_s: no; after idle_s: one collection, then none for every_s.
        clock.t += 0.5
        assert not policy.tick(busy=False)
        clock.t += 0.6
        assert policy.tick(busy=False) and policy.full_collections == 1
        clock.t += 5.0
        assert not policy.tick(busy=False)
        clock.t += 6.0
        assert policy.tick(busy=False) and policy.full_collections == 2
    finally:
        policy.uninstall()
    assert gc.get_threshold() == before and gc.get_freeze_count() == 0


def test_two_windows_restore_the_thresholds_once_both_are_gone() -> None:
    before = gc.get_threshold()
    a, b = GcPolicy(), GcPolicy()
    a.install()
    b.install()
    a.uninstall()
    assert gc.get_threshold() == GcPolicy.THRESHOLDS  # b still holds the policy
    b.uninstall()
    assert gc.get_threshold() == before

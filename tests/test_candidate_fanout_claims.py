"""The fan-out's claims (service.placement.candidate_fanout) on a real Redis (the embedded
redis-server) and a blob directory, without workers: a part whose claimant went away is planned by
the planning process once its claim lapses, the placement unchanged; a cancel while waiting for a
claimed part ends the planning and leaves no inputs, parts or claims behind."""

from __future__ import annotations

import json

import pytest
import redis

from farfield.core import procedural
from farfield.core.placement.candidate_parts import node_ranges
from farfield.core.placement.cost_model import primitive_model
from farfield.core.placement.planner import PlacementSettings, place
from farfield.service.blobs import LocalBlobStore
from farfield.service.embedded_redis import EmbeddedRedis
from farfield.service.placement.candidate_fanout import _fan_out, run_part

SCENE = procedural.city(25, seed=1, detail=8)
SETTINGS = PlacementSettings(t_max=600.0, model=primitive_model(), vdi_deg=45.0, options={"resolution": 64},
                             cpv_size=20.0)  # fmt: skip
VIEW = ([10.0, 2.0, 10.0], [70.0, 6.0, 70.0])


@pytest.fixture(scope="module")
def claims(tmp_path_factory):
    broker = EmbeddedRedis(tmp_path_factory.mktemp("redis")).start()
    try:
        yield redis.Redis.from_url(broker.url)
    finally:
        broker.stop()


class Cancelled(Exception):
    pass


def _hook(blobs, claims, prefix, before=None, progress=None):
    def candidates(inputs, report):
        ranges = node_ranges(inputs, 3)
        if before is not None:
            before(ranges)
        return _fan_out(blobs, claims, lambda *_: None, prefix, inputs, ranges, progress or report)

    return candidates


def test_a_part_whose_claim_lapsed_is_planned_here_and_a_stored_part_is_read(claims, tmp_path, caplog):
    blobs = LocalBlobStore(tmp_path / "blobs")
    prefix = "jobs/j/candidate-parts/lapsed"

    def before(ranges):  # part 0 held by a claimant that goes away; part 1 stored by a worker
        assert run_part(blobs, prefix, 1, ranges[1].start, ranges[1].stop, claims) == "stored"
        assert run_part(blobs, prefix, 1, ranges[1].start, ranges[1].stop, claims) == "taken"
        claims.set(f"farfield:{prefix}:claim-0", b"gone-worker", px=300)

    def candidates(inputs, report):
        blobs.put_bytes(f"{prefix}/inputs.pickle", inputs.dumps())  # as _fan_out stores them before sending
        ranges = node_ranges(inputs, 3)
        before(ranges)
        return _fan_out(blobs, claims, lambda *_: None, prefix, inputs, ranges, report)

    one = place(SCENE, *VIEW, SETTINGS)
    split = place(SCENE, *VIEW, SETTINGS, candidates=candidates)
    assert one.summary["candidates"] > 5
    assert "part 0 was left by its worker" in caplog.text  # taken over after the claim lapsed
    assert json.dumps(split.to_dict(), sort_keys=True) == json.dumps(one.to_dict(), sort_keys=True)
    assert not blobs.list_files(prefix) and not claims.keys(f"farfield:{prefix}:*")
    assert run_part(blobs, prefix, 2, 0, 1, claims) == "gone"  # a late part task does nothing


def test_a_cancel_while_waiting_for_a_claimed_part_leaves_nothing_behind(claims, tmp_path):
    blobs = LocalBlobStore(tmp_path / "blobs")
    prefix = "jobs/j/candidate-parts/cancelled"
    polls = []

    def before(ranges):  # a worker holds part 2 and never stores it
        claims.set(f"farfield:{prefix}:claim-2", b"slow-worker", ex=60)

    def progress(done, total):
        polls.append((done, total))
        if len(polls) > 5 and done < total:
            raise Cancelled

    with pytest.raises(Cancelled):
        place(SCENE, *VIEW, SETTINGS, candidates=_hook(blobs, claims, prefix, before, progress))
    assert polls and polls[-1][0] < polls[-1][1]
    assert not blobs.list_files(prefix) and not claims.keys(f"farfield:{prefix}:*")

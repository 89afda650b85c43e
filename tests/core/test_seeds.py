"""Seed streams are distinct from each other and far from a fit's round streams."""
from softsbi.core import seeds
from softsbi.core import defaults


def test_the_named_seed_streams_are_distinct_and_apart_from_the_rounds_streams():
    values = list(seeds.STREAMS.values())
    assert len(set(values)) == len(values), seeds.STREAMS
    # a fit's rounds use streams 0 .. rounds - 1; the evaluation's stream follows its last round
    assert min(v for v in values if v != seeds.SENSOR_VIEW_STREAM) > 100 * defaults.ROUNDS
    assert seeds.eval_stream(defaults.ROUNDS) not in values
    assert seeds.surface_seed(3) == seeds.SURFACE_SEED + 3

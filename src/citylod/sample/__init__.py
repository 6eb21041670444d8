"""The synthetic sample city: an analytic scene (:mod:`.city`) and the files written from it (:mod:`.files`,
:mod:`.gml`). It reads nothing; it exists so demos, tests and benchmarks have data with a known truth."""

from citylod.sample.files import SampleInfo, make_sample

__all__ = ["SampleInfo", "make_sample"]

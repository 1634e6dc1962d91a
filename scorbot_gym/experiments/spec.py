"""What a sweep runs: a protocol x estimators x occlusion levels x objects, under one seed.

Estimators are named by a small *spec* string resolved through :func:`pose.registry.make_estimator`:
``name`` or ``name(param=value, ...)`` with Python literal values, e.g. ``manifold``,
``manifold(allocentric=True)``, ``manifold(bunches__n_bunches=4)`` (a nested stage parameter,
set with ``set_params``). The spec string is also the estimator's label in every result, so two
variants of one estimator stay apart. An ablation is therefore a list of names; nothing is
registered or flagged for it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from scorbot_gym.data.perturbations import Perturbation


@dataclass(frozen=True)
class EstimatorSpec:
    """A registered estimator name plus keyword parameters; ``str()`` is the canonical label."""

    name: str
    params: tuple[tuple[str, Any], ...] = ()

    @classmethod
    def parse(cls, text: str) -> EstimatorSpec:
        from pose.registry import parse_spec

        name, params = parse_spec(text)
        return cls(name, tuple(sorted(params.items())))

    def make(self) -> Any:
        """A new estimator: plain parameters go to the registered factory, nested ones
        (``stage__param``, scikit-learn's convention) through ``set_params`` afterwards."""
        from pose.registry import make_with_params

        return make_with_params(self.name, dict(self.params))

    def __str__(self) -> str:
        if not self.params:
            return self.name
        return f"{self.name}({', '.join(f'{k}={v!r}' for k, v in self.params)})"


def split_estimators(text: str) -> list[str]:
    """Split ``a,b(x=1, y=2),c`` on the commas outside parentheses."""
    out, depth, cur = [], 0, []
    for ch in text:
        depth += (ch in "([{") - (ch in ")]}")
        if ch == "," and depth == 0:
            out.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
    out.append("".join(cur).strip())
    return [s for s in out if s]


def parse_occlusions(text: str) -> tuple[float, ...]:
    """Percent levels as ``START:STOP:STEP`` (inclusive stop, e.g. ``0:95:5``) or a comma list
    (``0,50``), returned as fractions."""
    try:
        if ":" in text:
            start, stop, step = (float(v) for v in text.split(":"))
            if step <= 0:
                raise ValueError("step must be positive")
            n = int(round((stop - start) / step)) + 1
            pct = [start + i * step for i in range(max(n, 0)) if start + i * step <= stop + 1e-9]
        else:
            pct = [float(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise ValueError(
            f"occlusion levels must be START:STOP:STEP or a comma list of percentages "
            f"(e.g. 0:95:5 or 0,50), got {text!r}"
        ) from exc
    if not pct or any(not 0 <= p <= 95 for p in pct):
        raise ValueError(f"occlusion percentages must lie within 0..95, got {text!r}")
    return tuple(round(p / 100.0, 4) for p in pct)


@dataclass(frozen=True)
class SweepSpec:
    """One sweep. ``test_views`` / ``train_stride`` shrink a protocol for quick runs (the first
    ``test_views`` held-out poses — on ``clutter`` the first scenes, whose views the bins then
    share —, every ``train_stride``-th training view); both are written into the results so a
    reduced figure is never mistaken for the full protocol."""

    protocol: str
    estimators: tuple[str, ...]
    occlusions: tuple[float, ...] = (0.0,)
    objects: tuple[str, ...] = ()
    seed: int = 0
    width: int = 320
    height: int = 240
    test_views: int | None = None
    train_stride: int = 1
    perturbation: Perturbation = field(default_factory=Perturbation)

    def __post_init__(self) -> None:
        from pose.registry import estimator_names
        from scorbot_gym.data.protocols import get_protocol
        from scorbot_gym.objects import get_object

        protocol = get_protocol(self.protocol)
        if not self.estimators:
            raise ValueError("a sweep needs at least one estimator")
        known = estimator_names()
        for e in self.estimators:
            spec = EstimatorSpec.parse(e)
            if spec.name not in known:
                raise ValueError(f"unknown estimator {spec.name!r}; registered: {', '.join(known)}")
            spec.make()  # a parameter it does not have is an input error before any trial runs
        if not self.occlusions or any(not 0.0 <= o <= 0.95 for o in self.occlusions):
            raise ValueError(
                f"occlusions must be fractions within [0, 0.95], got {self.occlusions}"
            )
        if protocol.clutter_distractors is not None:  # levels are bins of measured occlusion
            bad = [o for o in self.occlusions if not any(abs(o - b) < 1e-9 for b in
                                                         protocol.occlusions)]  # fmt: skip
            if bad:
                edges = ",".join(f"{100 * b:.0f}" for b in protocol.occlusions)
                raise ValueError(
                    f"protocol {self.protocol!r} measures occlusion and bins it: levels must be "
                    f"bin edges among {edges} (percent), got {[100 * o for o in bad]}"
                )
        for o in self.objects:
            get_object(o)
        if self.test_views is not None and self.test_views < 1:
            raise ValueError(f"test_views must be >= 1 or None, got {self.test_views}")
        if self.train_stride < 1:
            raise ValueError(f"train_stride must be >= 1, got {self.train_stride}")

    @property
    def object_names(self) -> tuple[str, ...]:
        from scorbot_gym.objects import object_names

        return self.objects or tuple(object_names())

    @property
    def estimator_specs(self) -> tuple[EstimatorSpec, ...]:
        return tuple(EstimatorSpec.parse(e) for e in self.estimators)

    def to_dict(self) -> dict:
        from scorbot_gym.data.protocols import describe

        d = asdict(self)
        d["estimators"] = [str(s) for s in self.estimator_specs]
        d["objects"] = list(self.object_names)
        d["occlusions"] = list(self.occlusions)
        d["perturbation"] = self.perturbation.to_dict()
        d["protocol_info"] = describe([self.protocol])[0]
        return d


def sweep(
    protocol: str,
    estimators: Sequence[str] | str,
    occlusions: Sequence[float] | str = (0.0,),
    **kw: Any,
) -> SweepSpec:
    """Convenience constructor accepting the CLI's string forms."""
    ests = split_estimators(estimators) if isinstance(estimators, str) else list(estimators)
    occ = parse_occlusions(occlusions) if isinstance(occlusions, str) else tuple(occlusions)
    ests = [str(EstimatorSpec.parse(e)) for e in ests]
    return SweepSpec(protocol, tuple(ests), occ, **kw)

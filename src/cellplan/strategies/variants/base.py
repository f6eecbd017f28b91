"""The one seam for the Section VI extensions of the strategies paper: :class:`Variant`.

Section V of Sharma, LaValle and Hutchinson (1996) solves one model: one request at a
time, certain fine motions, exact moves, a stationary process. Section VI sketches four
extensions, each a *variant* of that model:

* VI-1 time-varying models and conveyors (:mod:`.conveyors`; the model: :mod:`.periodic`),
* VI-2 simultaneous requests (:mod:`.simultaneous`; the model: :mod:`.pending`),
* VI-3 fine motions that can fail (:mod:`.failures`),
* VI-4 noisy motion (:mod:`.noise`).

A variant supplies, in its own module and nowhere else, everything that differs from
Section V: its scenario checks, its modes and FMP outcomes (the model it assembles), its
live-state rule, its strategy-file keys, its simulation rules and its ``describe`` line.
The Section V model is the problem with no variant active. Modules outside
``variants/`` never test which variant they have: they call the hooks of the active
variants, which the compiled problem (:class:`~cellplan.strategies.model.spec.ProblemSpec`)
carries, and the kernels read the model's tables.

Registry (Gymnasium style, but immutable): :data:`cellplan.strategies.variants.registry.VARIANTS`
maps a name to its instance; adding a fifth extension is one module with a subclass of
:class:`Variant` and one line there (docs/strategies.md, "How to add a variant").

Import rule: a variant imports the model (``model/``), the model never imports a
variant. Each hook's docstring says who calls it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from cellplan.errors import Problem
from cellplan.strategies.model.actions import ActionSet
from cellplan.strategies.model.spec import Build, LayerCounts

if TYPE_CHECKING:
    from cellplan.strategies.model.layered import LayeredMDP


@dataclass(frozen=True)
class SimEvent:
    """An event of a simulated stage: ``kind`` (``fmp_failed``, ``reject``, ...) and its
    text, as :class:`~cellplan.strategies.sim.simulate.Simulation` records them."""

    kind: str
    detail: str


class Variant:
    """One Section VI extension of the Section V model. Subclass it and override the hooks
    that differ from Section V; every default here is the Section V behaviour.

    Class attributes: ``name`` (the registry key), ``paper`` (the section of the paper it
    follows), ``keys`` (the ``strategy:`` keys that switch it on, for messages) and
    ``file_keys`` (the keys of a strategy file's metadata it owns).
    """

    name: ClassVar[str] = ""
    paper: ClassVar[str] = ""
    keys: ClassVar[tuple[str, ...]] = ()
    file_keys: ClassVar[tuple[str, ...]] = ()

    # --- scenario ------------------------------------------------------------------------

    def active(self, section: Any) -> bool:
        """Whether ``section`` (a ``strategy:`` section) asks for this variant.

        Called by :meth:`~cellplan.strategies.section.StrategySection.compile` (which puts
        the active variants in the problem specification) and by its ``check``.
        """
        return False

    def in_model(self, mdp: LayeredMDP) -> bool:
        """Whether a model, built or read from a strategy file, has this variant's structure.

        Called by :func:`~cellplan.strategies.variants.registry.model_variants`, for a
        model read from a file (a built model carries its variants: ``mdp.variants``).
        """
        return False

    def check(self, section: Any, scenario: Any) -> list[Problem]:
        """One :class:`~cellplan.errors.Problem` per mistake in this variant's keys.

        Called by :meth:`~cellplan.strategies.section.StrategySection.check` for every
        variant, active or not (a check may refuse a key that is given but unused).
        """
        return []

    def reserved_regions(self, section: Any) -> set[str]:
        """Destinations this variant reserves for itself, left out of ``requests: all``.

        Called by :meth:`~cellplan.strategies.section.StrategySection.request_list`.
        """
        return set()

    # --- model ---------------------------------------------------------------------------

    def obstacle_exempt(self, section: Any) -> frozenset[str]:
        """Sources that are never obstacles (equations (1)-(3) make the others so).

        Called by :func:`~cellplan.strategies.model.mdp.build_model` before the bitmaps.
        """
        return frozenset()

    def actions(
        self, section: Any, robot: Any, empty: ActionSet, carrying: Mapping[str, ActionSet]
    ) -> tuple[ActionSet, dict[str, ActionSet]]:
        """The action sets while empty and while carrying each part (equation (5)).

        Called by :func:`~cellplan.strategies.model.mdp.action_sets`, in registry order.
        """
        return empty, dict(carrying)

    def assemble(self, build: Build) -> LayeredMDP | None:
        """The layered MDP of this variant's modes and FMP outcomes, or None to leave the
        Section V layout (NR, W, C) to :func:`~cellplan.strategies.model.mdp.assemble`.

        Called by :func:`~cellplan.strategies.model.mdp.build_model`; the first active
        variant that returns a model wins (the checks refuse combinations not built).
        ``build_model`` then sets ``mdp.variants`` to the active variants, so that their
        :meth:`live` and :meth:`problems` apply wherever the model goes (a rebuild of its
        moves, the simulator's sub-models; a model read from a strategy file finds its
        variants with :func:`~cellplan.strategies.variants.registry.model_variants`).
        """
        return None

    def extend(self, build: Build, mdp: LayeredMDP) -> LayeredMDP:
        """The model after this variant's change to an assembled one (the phases of a
        time-varying model, say); ``mdp`` unchanged by default.

        Called by :func:`~cellplan.strategies.model.mdp.build_model` after
        :meth:`assemble`, in registry order.
        """
        return mdp

    def build_problems(self, build: Build, mdp: LayeredMDP) -> list[Problem] | None:
        """One problem per request the built model can never serve, or None to leave the
        check to :func:`~cellplan.strategies.model.live.live_problems`.

        Called by :func:`~cellplan.strategies.model.mdp.build_model` once, before solving.
        """
        return None

    def live(self, mdp: LayeredMDP) -> bool:
        """Restrict ``mdp.live`` by this variant's live-state rule (in place) and return
        True, or return False to leave it to the Section V rule.

        Called by :func:`~cellplan.strategies.model.live.compute_live` for each variant
        the model carries (``mdp.variants``, set by ``build_model``).
        """
        return False

    def problems(self, mdp: LayeredMDP) -> list[Problem] | None:
        """The unservable requests by this variant's rule, or None for Section V's.

        Called by :func:`~cellplan.strategies.model.live.live_problems` for each variant
        the model carries (after a rebuild of its moves, too).
        """
        return None

    def layers(self, section: Any, requests: Sequence[Any], counts: LayerCounts) -> LayerCounts:
        """The model's size before it is built, for the memory estimate.

        Called by :func:`~cellplan.strategies.model.memory.estimate_memory`, in registry
        order, with the Section V counts.
        """
        return counts

    # --- solver --------------------------------------------------------------------------

    def check_solver(self, method: str, damping: float) -> list[str]:
        """Why the solver ``method`` (with ``damping``, for ``general``) cannot solve this
        variant's models (one line each); empty when it can.

        Called by :func:`~cellplan.strategies.solve.solver.method_problem` for each variant
        of the model (:func:`~cellplan.strategies.variants.registry.model_variants`).
        """
        return []

    # --- strategy files -------------------------------------------------------------------

    def file_meta(self, mdp: LayeredMDP) -> dict[str, Any]:
        """This variant's keys (:attr:`file_keys`) of a strategy file's metadata.

        Called by :mod:`cellplan.strategies.policy.fileformat` when it writes a file.
        """
        return {}

    def file_modes(self, meta: Any, spec: Any, fail: Any) -> bool:
        """Check a strategy file's ``meta.modes`` against the compiled scenario ``spec``
        and return True when this variant lays the modes out its own way; False leaves
        them to the Section V check (NR, W, C, X per phase).

        Called by :func:`cellplan.strategies.policy.fileformat.read_strategy` with a
        scenario; ``fail(message)`` makes the error to raise.
        """
        return False

    # --- describe ---------------------------------------------------------------------------

    def modes_line(self, mdp: LayeredMDP, section: Any) -> str | None:
        """The ``assembly modes`` line of ``cellplan validate`` for this variant's modes, or
        None to keep the Section V line. Called by :func:`cellplan.strategies.plugin.describe`."""
        return None

    def facts(self, mdp: LayeredMDP) -> list[tuple[str, str, Any, str]]:
        """Extra ``cellplan validate`` facts ``(key, label, value, text)``.

        Called by :func:`cellplan.strategies.plugin.describe` after the modes line.
        """
        return []

    # --- simulation (the simulator's side is sim/simulate.py) -------------------------------

    def policies(self) -> tuple[str, ...] | None:
        """The simulator's policies for this variant's model, or None for Section V's
        (``optimal``, ``reactive``, ``home``). Called by
        :meth:`~cellplan.strategies.sim.options.SimulationOptions.problems` to check
        ``policy``. A variant whose process the Section V simulator cannot run names its
        own simulator in :data:`cellplan.strategies.variants.simulators.SIMULATORS`."""
        return None

    def landing(self, mdp: LayeredMDP, rng: np.random.Generator) -> int | None:
        """Where a commanded move lands this stage: the index of its noisy landing, or
        None to land as commanded (Section V). Called by
        :func:`~cellplan.strategies.sim.simulate.simulate` once per stage of motion (a
        variant that draws takes its numbers from ``rng``, the run's one stream)."""
        return None

    def fmp_event(self, mdp: LayeredMDP, layer: int, outcome: int) -> SimEvent | None:
        """The event of an FMP whose outcome ``outcome`` (an index into the model's
        outcome table, drawn by the simulator from ``out_prob``) the simulator drew in
        ``layer``, or None for the Section V pick or place. Called by
        :func:`~cellplan.strategies.sim.simulate.simulate` after each FMP; an event of
        kind ``fmp_failed`` counts as a failure of the request, and an outcome that leads
        from another kind of mode back to a W mode puts the part at that W mode's source
        (its pick-up to do again)."""
        return None

    def region_offset(self, mdp: LayeredMDP, region: str, layer: int) -> tuple[float, float]:
        """How far ``region`` has moved from its scenario position in ``layer``.

        Called by :meth:`~cellplan.strategies.policy.regions.RegionTest.option` before the
        exact region test of an FMP; ``(0, 0)`` in Section V.
        """
        return (0.0, 0.0)

    def lookahead(self, mdp: LayeredMDP) -> int | None:
        """The deepest lookahead the executor may plan in this variant's model, or None
        for no limit of its own. Called by
        :func:`~cellplan.strategies.policy.execution.default_depth`."""
        return None

    def fmp_options(self) -> bool:
        """Whether an FMP in this variant's model is a choice among options (Section
        VI-2), which the executor scores with rule (9) over the options the exact test
        confirms. Called by :class:`~cellplan.strategies.policy.execution.Executor`."""
        return False

    def describe(self) -> str:
        """One line for documentation and messages: the name and the paper's section."""
        return f"{self.name} ({self.paper}; strategy keys: {', '.join(self.keys)})"


def not_combined(model: str, given: Mapping[str, bool]) -> list[Problem]:
    """One line per key given (True) that is not built together with ``model`` yet."""
    return [
        Problem(f"strategy.{key}", f"cannot be combined with {model} yet")
        for key, on in given.items()
        if on
    ]

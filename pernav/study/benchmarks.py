"""The benchmarks' schedules: which drivers each benchmark preset drives, and each (town, round) cell classified
*late* or *on time* before any learner runs (docs/personal.md).

Explore's prompts are timed for the average driver with 0.8 s of slack; personal timing pays only for drivers
outside that slack. A cell is *late* when explore's "turn" prompts reach the driver after its commit point in at
least :data:`LATE_EXCESS` more of the prompts than the oracle's, from the driver's resolved profile alone
(:func:`pernav.env.policies.lateness`: analytic, no simulation, no learner).

- ``personal`` (the headroom benchmark): named users and population-prior draws, at least half of them late;
- ``sweep`` (the ``personal_sweep`` preset): the average driver with its reaction time shifted;
- ``split``: slow and quick population drivers, alternating;
- ``repeat``: two slow and two quick drivers, five drives each (the personalization curve).

The seeds, targets and judging of each benchmark's looks are protocols, not library: they live in
``recipes/benchmarks/`` (pre-registrations as data files).

Example:
    >>> cells = classify(personal_schedule(), ["Town1"])
    >>> sum(c["late"] for c in cells) >= len(cells) / 2
    True
    >>> [e.label for e in split_schedule()[3:6]]
    ['slow 0', 'quick 0', 'slow 1']
"""

from __future__ import annotations

from typing import Any

from pernav.env.policies import lateness
from pernav.study.schedule import Entry, paper_schedule
from pernav.world.drivers import POPULATION_AVERAGE, Population, resolve

__all__ = ["LATE_EXCESS", "PERSONAL_POPULATION_SEED", "POPULATION_DRAWS", "REPEAT_DRIVERS", "REPEAT_DRIVES",
           "REPEAT_POPULATION_SEED", "SCHEDULES", "SPLIT_DRIVERS", "SPLIT_POPULATION_SEED", "SWEEP_SHIFTS", "classify",
           "episodes", "offline_rounds", "personal_schedule", "repeat_schedule", "split_drivers", "split_schedule",
           "sweep_schedule"]

#: a cell is late when explore is late for the commit in at least this share more of the prompts than the oracle
LATE_EXCESS = 0.05
#: the seed of the headroom benchmark's population-prior drivers (fixed before any run; not the diagnostics panel's)
PERSONAL_POPULATION_SEED = 38
POPULATION_DRAWS = 8
_NAMED = [  # (label, user, context): four outside explore's slack, four inside
    ("user3", "user3", {}),
    ("user2", "user2", {}),
    ("user5", "user5", {}),
    ("user1 truck fog", "user1", {"vehicle": "cybertruck", "visual": "foggy"}),
    ("user4", "user4", {}),
    ("user6", "user6", {}),
    ("user7 wheel", "user7", {"equipment": "wheel"}),
    ("user1 wheel", "user1", {"equipment": "wheel"}),
]
#: the sweep: the average driver (average context) with its reaction time shifted by these seconds
SWEEP_SHIFTS = (-0.4, 0.0, 0.4, 0.8, 1.2)
#: the split benchmark's population-prior drivers (fixed before any run; used nowhere else)
SPLIT_POPULATION_SEED = 4848
SPLIT_DRIVERS = 5  # drivers of each half
#: the repeated-drives drivers: fresh draws (used nowhere else), two of each half, five drives each
REPEAT_POPULATION_SEED = 5151
REPEAT_DRIVERS = 2
REPEAT_DRIVES = 5


def offline_rounds() -> list[Entry]:
    """The default study's three offline rounds (user1), which every benchmark schedule starts with."""
    by_label = {e.label: e for e in paper_schedule()}
    return [by_label[x] for x in ("Offline 0", "Offline 1", "Offline 2")]


def personal_schedule() -> list[Entry]:
    """The ``personal`` preset's schedule (the headroom benchmark): the default study's three offline rounds (user1),
    then eight named-user rounds and :data:`POPULATION_DRAWS` population-prior rounds
    (``Population(seed=PERSONAL_POPULATION_SEED)``)."""
    entries = offline_rounds()
    entries += [Entry(label, "online", user, **context) for label, user, context in _NAMED]
    pop = Population(seed=PERSONAL_POPULATION_SEED)
    for i in range(POPULATION_DRAWS):
        profile, context = pop.sample()
        entries.append(Entry(f"population {i}", "online", profile.to_dict(), **context.to_dict()))
    return entries


def sweep_schedule() -> list[Entry]:
    """The ``personal_sweep`` preset's schedule: the default study's offline rounds, then one online round per
    reaction-time shift of the average driver (:data:`SWEEP_SHIFTS`; every other trait and the context average)."""
    entries = offline_rounds()
    for shift in SWEEP_SHIFTS:
        profile = {**POPULATION_AVERAGE.to_dict(), "reaction_time": round(POPULATION_AVERAGE.reaction_time + shift, 2)}
        entries.append(Entry(f"reaction {shift:+.1f} s", "online", profile))
    return entries


def split_drivers(population_seed: int, n: int) -> dict[str, list[tuple[Any, Any]]]:
    """The first ``n`` slow (outside explore's slack: late, :func:`classify`) and ``n`` quick (inside it) drivers drawn
    from ``Population(seed=population_seed)``, as ``{"slow": [(profile, context), ...], "quick": [...]}``; drivers
    in neither class (late for the oracle too) are skipped.

    >>> [len(v) for v in split_drivers(SPLIT_POPULATION_SEED, 2).values()]
    [2, 2]
    """
    pop, kinds = Population(seed=population_seed), {"slow": [], "quick": []}
    while min(len(v) for v in kinds.values()) < n:
        profile, context = pop.sample()
        late = lateness(resolve(profile, context))
        kind = "slow" if late["excess"] >= LATE_EXCESS else "quick" if late["explore"] < LATE_EXCESS else None
        if kind is not None and len(kinds[kind]) < n:
            kinds[kind].append((profile, context))
    return kinds


def split_schedule() -> list[Entry]:
    """The ``split`` preset's schedule, where the population's prior is no guide: the default study's offline rounds,
    then :data:`SPLIT_DRIVERS` slow drivers (outside explore's slack: the cell is late, :func:`classify`) and as many
    quick ones (inside it), alternating, the first draws of each kind from
    ``Population(seed=SPLIT_POPULATION_SEED)``. Re-timing everybody says early prompts to the quick half; keeping
    explore leaves the slow half late; only a learner that tells them apart serves both."""
    entries = offline_rounds()
    kinds = split_drivers(SPLIT_POPULATION_SEED, SPLIT_DRIVERS)
    for i in range(SPLIT_DRIVERS):
        for kind in ("slow", "quick"):
            profile, context = kinds[kind][i]
            entries.append(Entry(f"{kind} {i}", "online", profile.to_dict(), **context.to_dict()))
    return entries


def repeat_schedule() -> list[Entry]:
    """The ``repeat`` preset's schedule: the offline rounds, then :data:`REPEAT_DRIVES` rounds of each of
    :data:`REPEAT_DRIVERS` slow and as many quick drivers (``Population(seed=REPEAT_POPULATION_SEED)``), the drivers
    alternating within each pass. A driver's rounds share its profile and context, so the belief learner's
    posterior after one round is its prior in the next (the study's user key).

    >>> [e.label for e in repeat_schedule()[3:6]]
    ['slow 0 drive 1', 'quick 0 drive 1', 'slow 1 drive 1']
    """
    entries = offline_rounds()
    kinds = split_drivers(REPEAT_POPULATION_SEED, REPEAT_DRIVERS)
    for k in range(1, REPEAT_DRIVES + 1):
        for i in range(REPEAT_DRIVERS):
            for kind in ("slow", "quick"):
                profile, context = kinds[kind][i]
                entries.append(Entry(f"{kind} {i} drive {k}", "online", profile.to_dict(), **context.to_dict()))
    return entries


#: the benchmark schedules a preset may name (``schedule: split``)
SCHEDULES = {"personal": personal_schedule, "sweep": sweep_schedule, "split": split_schedule, "repeat": repeat_schedule}


def classify(entries: list[Entry], towns: list[str]) -> list[dict[str, Any]]:
    """Every online (town, round) cell with explore's and the oracle's late shares and its class, from the
    round's driver profile and context alone."""
    cells = []
    for town in towns:
        for e in entries:
            if e.phase != "online" or not e.runs_in(town) or e.drives:
                continue
            late = lateness(resolve(e.profile(), e.context()))
            cells.append({"town": town, "round": e.label, "explore_late": round(late["explore"], 4),
                          "oracle_late": round(late["oracle"], 4), "late": bool(late["excess"] >= LATE_EXCESS)})
    return cells


def episodes(results: list[dict[str, Any]]) -> dict[tuple, dict[str, dict[str, Any]]]:
    """``{(seed, town, round, route): {method: episode}}`` from studies' ``results.json`` (several studies of one
    seed, e.g. each with other methods, drive the same episodes and merge)."""
    out: dict[tuple, dict[str, dict[str, Any]]] = {}
    for result in results:
        seed = result["config"]["seed"]
        for it in result["iterations"]:
            if it["phase"] != "online":
                continue
            for town, methods in it["towns"].items():
                for method, figures in methods.items():
                    for e in figures["episodes"]:
                        out.setdefault((seed, town, it["label"], e["route"]), {})[method] = e
    return out

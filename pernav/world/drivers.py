"""Simulated drivers: personal profiles, context modifiers, named users and a population prior.

A :class:`DriverProfile` holds the canonical profile fields (docs/simulator.md); a :class:`Context` says which vehicle,
camera, visual condition and equipment the driver uses. :func:`resolve` combines both into the
effective parameters the simulated driver acts with.

Example:
    >>> p = named_user("user3")
    >>> d = resolve(p, Context(vehicle="cybertruck", visual="foggy"))
    >>> d.reaction_time > p.reaction_time  # fog slows reactions
    True
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np


class ProfileError(ValueError):
    """A driver profile or context value is unknown or out of range."""


# field -> (low, high, meaning); ranges from docs/simulator.md
PROFILE_RANGES: dict[str, tuple[float, float, str]] = {
    "reaction_time": (0.5, 2.5, "s from the end of an instruction's audio to acting on it"),
    "speed_factor": (0.8, 1.15, "desired speed / speed limit"),
    "turn_speed": (4.0, 9.0, "m/s through a turn"),
    "decision_time": (1.0, 3.0, "s before a junction at which the branch is committed"),
    "memory": (8.0, 30.0, "s an instruction stays in mind"),
    "steering_tau": (0.4, 1.2, "s, lateral response time constant"),
    "comfort_accel": (0.7, 3.0, "m/s^2"),
    "comfort_decel": (1.5, 5.0, "m/s^2"),
    "time_headway": (1.0, 2.2, "s, car following"),
    "compliance": (0.85, 0.99, "probability an understood instruction is followed"),
    "speech_tolerance": (0.0, 1.0, "how well fast speech is understood (0 poor, 1 good)"),
}

CONTEXT_CHOICES: dict[str, tuple[str, ...]] = {
    "vehicle": ("camaro", "cybertruck"),
    "camera": ("first_person", "third_person", "top"),
    "visual": ("normal", "rgb", "foggy"),
    "equipment": ("keyboard", "wheel"),
}


@dataclass(frozen=True)
class DriverProfile:
    """A driver's personal dynamics (docs/simulator.md). Every field is validated against its range.

    >>> DriverProfile(reaction_time=3.0)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    pernav.world.drivers.ProfileError: reaction_time=3.0 is out of range [0.5, 2.5] (s from the end of ...)
    """

    reaction_time: float = 1.2
    speed_factor: float = 1.0
    turn_speed: float = 6.5
    decision_time: float = 2.0
    memory: float = 18.0
    steering_tau: float = 0.7
    comfort_accel: float = 1.8
    comfort_decel: float = 3.2
    time_headway: float = 1.6
    compliance: float = 0.95
    speech_tolerance: float = 0.6

    def __post_init__(self) -> None:
        for name, (lo, hi, meaning) in PROFILE_RANGES.items():
            value = getattr(self, name)
            # any real number (numpy scalars too), not bool; huge ints overflow to inf (out of range)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
                raise ProfileError(f"{name}={value!r} must be a number in [{lo}, {hi}] ({meaning})")
            try:
                number = float(value)
            except OverflowError:
                number = math.inf
            if not math.isfinite(number) or not lo <= number <= hi:
                raise ProfileError(f"{name}={value!r} is out of range [{lo}, {hi}] ({meaning})")
            object.__setattr__(self, name, number)

    def to_dict(self) -> dict[str, float]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> DriverProfile:
        """Build from a mapping; unknown keys are an error naming the key and the allowed ones."""
        if not isinstance(data, Mapping):
            raise ProfileError(f"a profile must be a mapping of {', '.join(PROFILE_RANGES)}, not {type(data).__name__}")
        unknown = sorted(set(data) - set(PROFILE_RANGES), key=str)  # keys of any type (YAML: 1, null)
        if unknown:
            raise ProfileError(f"unknown profile field {unknown[0]!r}; allowed: {', '.join(PROFILE_RANGES)}")
        return cls(**data)


@dataclass(frozen=True)
class Context:
    """Vehicle, camera, visual condition and control equipment of a drive.

    >>> Context(visual="rain")
    Traceback (most recent call last):
    ...
    pernav.world.drivers.ProfileError: unknown visual 'rain'; allowed: normal, rgb, foggy
    """

    vehicle: str = "camaro"
    camera: str = "third_person"
    visual: str = "normal"
    equipment: str = "keyboard"

    def __post_init__(self) -> None:
        for name, allowed in CONTEXT_CHOICES.items():
            value = getattr(self, name)
            if value not in allowed:
                raise ProfileError(f"unknown {name} {value!r}; allowed: {', '.join(allowed)}")

    def to_dict(self) -> dict[str, str]:
        return dataclasses.asdict(self)


#: coefficient of variation of one driver's reaction time from one prompt to the next: brake reaction to an
#: expected signal 1.25 s with SD 0.46 s (Green 2000, "How long does it take to stop?"; Johansson & Rumar
#: 1971), i.e. SD ~0.37 x the mean; the spread grows with the mean (slow drivers are also the variable ones)
REACTION_CV = 0.37


@dataclass(frozen=True)
class VehicleModel:
    """Physical vehicle: size, steering limit, braking and grip (lateral acceleration limit)."""

    name: str
    length: float
    width: float
    max_steering: float  # rad
    max_decel: float  # m/s^2, emergency braking
    max_lateral_accel: float  # m/s^2, grip: beyond it the car runs wide
    accel_scale: float  # multiplies the driver's comfortable acceleration


VEHICLES = {
    "camaro": VehicleModel("camaro", 4.6, 1.9, 0.75, 8.0, 7.0, 1.0),
    "cybertruck": VehicleModel("cybertruck", 5.9, 2.4, 0.62, 6.0, 4.5, 0.7),
}


@dataclass(frozen=True)
class Driver:
    """Effective driver parameters: profile × context (what the simulated driver acts with)."""

    profile: DriverProfile
    context: Context
    vehicle: VehicleModel
    reaction_time: float
    speed_factor: float
    turn_speed: float
    decision_time: float
    memory: float
    steering_tau: float
    comfort_accel: float
    comfort_decel: float
    time_headway: float
    compliance: float
    speech_tolerance: float
    sight_distance: float  # m at which junctions and roundabouts are seen
    speed_misjudgement: float  # perceived / true speed when planning braking (top view < 1)
    keyboard: bool

    @property
    def reaction_sd(self) -> float:
        """SD of the reaction time from one prompt to the next (s): ``REACTION_CV`` x the mean."""
        return REACTION_CV * self.reaction_time

    def reaction_draw(self, z: float) -> float:
        """One prompt's reaction time from a standard normal draw ``z``: lognormal with mean
        ``reaction_time`` and SD ``reaction_sd`` (reaction times are right-skewed), capped at 3x the mean.

        >>> d = resolve(DriverProfile(), Context())
        >>> round(d.reaction_draw(0.0), 3) < d.reaction_time < d.reaction_draw(1.0)
        True
        """
        sigma = math.sqrt(math.log1p(REACTION_CV**2))
        mu = math.log(self.reaction_time) - sigma**2 / 2
        return min(math.exp(mu + sigma * z), 3.0 * self.reaction_time)

    def understanding(self, playback: str) -> float:
        """Probability that an instruction played at ``playback`` speed is understood."""
        if playback == "slower":
            return 0.985
        if playback == "faster":
            return 0.97 - 0.45 * (1.0 - self.speech_tolerance)
        return 0.97 - 0.05 * (1.0 - self.speech_tolerance)


_VISUAL = {  # sight distance (m), speed multiplier, added reaction time (s)
    "normal": (110.0, 1.0, 0.0),
    "rgb": (80.0, 0.97, 0.15),
    "foggy": (38.0, 0.88, 0.45),
}
_CAMERA = {  # sight multiplier, speed misjudgement, added decision time (s)
    "first_person": (0.8, 1.0, 0.0),
    "third_person": (1.0, 1.0, 0.0),
    "top": (1.3, 0.85, -0.2),
}


# the long, heavy truck: slower through turns, gentler comfortable braking, and the branch chosen earlier
# (a long vehicle is set up for a turn before it: lane position, swing out)
TRUCK_TURN_SPEED, TRUCK_DECEL, TRUCK_DECISION = 0.75, 0.75, 0.8


def resolve(profile: DriverProfile, context: Context) -> Driver:
    """Apply the context modifiers to a profile (docs/simulator.md)."""
    sight, speed_mult, extra_rt = _VISUAL[context.visual]
    sight_mult, misjudge, extra_dt = _CAMERA[context.camera]
    veh = VEHICLES[context.vehicle]
    keyboard = context.equipment == "keyboard"
    truck = context.vehicle == "cybertruck"
    return Driver(
        profile=profile,
        context=context,
        vehicle=veh,
        reaction_time=profile.reaction_time + extra_rt,
        speed_factor=profile.speed_factor * speed_mult,
        turn_speed=profile.turn_speed * (TRUCK_TURN_SPEED if truck else 1.0),
        decision_time=max(0.8, profile.decision_time + extra_dt + (TRUCK_DECISION if truck else 0.0)),
        memory=profile.memory,
        steering_tau=profile.steering_tau * (1.25 if truck else 1.0) * (1.15 if keyboard else 1.0),
        comfort_accel=profile.comfort_accel * veh.accel_scale,
        comfort_decel=profile.comfort_decel * (TRUCK_DECEL if truck else 1.0),
        time_headway=profile.time_headway,
        compliance=profile.compliance,
        speech_tolerance=profile.speech_tolerance,
        sight_distance=sight * sight_mult,
        speed_misjudgement=misjudge,
        keyboard=keyboard,
    )


NAMED_USERS: dict[str, DriverProfile] = {
    # experienced keyboard driver (the paper's user 1)
    "user1": DriverProfile(0.9, 1.0, 7.0, 1.8, 20.0, 0.55, 2.0, 3.5, 1.4, 0.97, 0.8),
    # novice: slow to react, hesitant, forgets
    "user2": DriverProfile(1.6, 0.9, 5.0, 2.8, 12.0, 0.9, 1.2, 2.5, 2.0, 0.92, 0.4),
    # elderly-like: slow reactions, slow speed, needs early prompts, poor with fast speech
    "user3": DriverProfile(2.3, 0.82, 4.5, 3.0, 10.0, 1.1, 1.0, 2.0, 2.2, 0.95, 0.2),
    # fast and aggressive
    "user4": DriverProfile(0.6, 1.15, 8.5, 1.1, 25.0, 0.45, 2.8, 4.5, 1.0, 0.9, 0.9),
    # cautious
    "user5": DriverProfile(1.3, 0.85, 5.0, 2.5, 18.0, 0.8, 1.2, 2.2, 2.1, 0.98, 0.6),
    # distracted, low compliance, short memory
    "user6": DriverProfile(1.5, 1.0, 6.5, 1.5, 8.0, 0.7, 2.0, 3.5, 1.3, 0.85, 0.5),
    # average
    "user7": DriverProfile(1.2, 1.0, 6.5, 2.0, 18.0, 0.7, 1.8, 3.2, 1.6, 0.95, 0.6),
}

POPULATION_AVERAGE = DriverProfile()  # the midpoint of the typical ranges; explore is timed for it
AVERAGE_CONTEXT = Context()


def named_user(name: str) -> DriverProfile:
    """One of ``user1`` … ``user7``."""
    if not isinstance(name, str) or name not in NAMED_USERS:
        raise ProfileError(f"unknown user {name!r}; choose one of {', '.join(NAMED_USERS)} or a profile file")
    return NAMED_USERS[name]


@dataclass
class Population:
    """Prior over drivers: each profile field uniform in its :data:`PROFILE_RANGES` range (``ranges`` may narrow
    them), contexts uniform over their choices unless fixed.

    >>> pop = Population(seed=0)
    >>> p, c = pop.sample()
    >>> 0.5 <= p.reaction_time <= 2.5
    True
    """

    seed: int = 0
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    fixed_context: Context | None = None

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        for name, (lo, hi) in self.ranges.items():
            if name not in PROFILE_RANGES:
                raise ProfileError(f"unknown profile field {name!r}; allowed: {', '.join(PROFILE_RANGES)}")
            full_lo, full_hi, _ = PROFILE_RANGES[name]
            if not full_lo <= lo <= hi <= full_hi:
                raise ProfileError(f"range of {name} [{lo}, {hi}] must lie inside [{full_lo}, {full_hi}]")

    def sample(self) -> tuple[DriverProfile, Context]:
        values = {}
        for name, (lo, hi, _) in PROFILE_RANGES.items():
            lo, hi = self.ranges.get(name, (lo, hi))
            values[name] = float(self.rng.uniform(lo, hi))
        context = self.fixed_context or Context(
            **{k: str(self.rng.choice(v)) for k, v in CONTEXT_CHOICES.items()}
        )
        return DriverProfile(**values), context


#: the seed of the diagnostics panel's population samples (fixed before any run)
PANEL_POPULATION_SEED = 2022


def population_samples(n: int, seed: int = PANEL_POPULATION_SEED) -> list[tuple[DriverProfile, Context]]:
    """The first ``n`` draws of ``Population(seed=seed)``: the population samples of the diagnostics panel
    (:mod:`pernav.diagnostics.panel`, and written out in ``docs/research/configs/headroom.yaml``), so no figure is
    tuned to the named users alone.

    >>> a, b = population_samples(2)
    >>> a == population_samples(1)[0] and a != b
    True
    """
    pop = Population(seed=seed)
    return [pop.sample() for _ in range(n)]

"""Property-based tests (hypothesis) of every validation on user input (docs/reliability.md).

- ``DriverProfile``: values inside ``PROFILE_RANGES`` construct and round-trip; anything else (out of
  range, wrong type, nan/inf, unknown field) is a ``ProfileError`` naming the field (and the range).
- ``load_user``: random mappings of profile fields, context keys and a base user.
- Schedules: random valid schedules parse; one random corruption is a ``ScheduleError`` naming the entry
  index and the field; random YAML/JSON text never raises anything but ``ScheduleError``.
- CLI: random bad values for ``pernav drive``/``study``/``towns``/``bench`` exit with code 2 and one line
  on stderr (argparse's own usage errors: ``SystemExit(2)``), never a traceback, never overwrite.

Every example is fast: only inputs that fail validation reach the CLI, and the heavy functions (driving
an episode, running a town of the study) are patched to fail the test if they are ever reached.
"""

from __future__ import annotations

import json
import math
import re
import string
import tempfile
from pathlib import Path
from unittest import mock

import pytest
import yaml
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from pernav.cli import MAX_TRAFFIC, main
from pernav.env.navigation import load_user
from pernav.study.config import PRESETS
from pernav.study.schedule import FIELDS, ScheduleError, load_schedule, parse_schedule
from pernav.world.constants import TOWN_NAMES
from pernav.world.drivers import (
    CONTEXT_CHOICES,
    NAMED_USERS,
    PROFILE_RANGES,
    Context,
    DriverProfile,
    ProfileError,
)

FAST = settings(max_examples=150, deadline=None, derandomize=True)
CLI = settings(max_examples=40, deadline=None, derandomize=True,
               suppress_health_check=[HealthCheck.function_scoped_fixture])

FIELD_NAMES = list(PROFILE_RANGES)
TMP = Path(tempfile.mkdtemp(prefix="pernav-properties-"))  # no tmp_path: hypothesis reuses one test call


# ----- strategies -----------------------------------------------------------------------------------------
def in_range(name: str) -> st.SearchStrategy:
    lo, hi, _ = PROFILE_RANGES[name]
    if math.ceil(lo) > math.floor(hi):  # no integer inside (compliance)
        return st.floats(lo, hi)
    return st.one_of(st.floats(lo, hi), st.integers(math.ceil(lo), math.floor(hi)))


def outside(name: str) -> st.SearchStrategy:
    lo, hi, _ = PROFILE_RANGES[name]
    return st.one_of(st.floats(max_value=lo, exclude_max=True, allow_nan=False, allow_infinity=False),
                     st.floats(min_value=hi, exclude_min=True, allow_nan=False, allow_infinity=False),
                     st.integers(max_value=math.ceil(lo) - 1), st.integers(min_value=math.floor(hi) + 1),
                     st.sampled_from([10**400, -(10**400)]))


NOT_A_NUMBER = st.one_of(st.text(max_size=8), st.none(), st.booleans(), st.lists(st.floats(), max_size=2),
                         st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))
NON_FINITE = st.sampled_from([math.nan, math.inf, -math.inf])

profile_values = st.fixed_dictionaries({}, optional={name: in_range(name) for name in FIELD_NAMES})
context_values = st.fixed_dictionaries({}, optional={k: st.sampled_from(v) for k, v in CONTEXT_CHOICES.items()})
unknown_keys = st.one_of(st.text(max_size=12), st.integers(), st.none(), st.floats(allow_nan=False)).filter(
    lambda k: k not in PROFILE_RANGES and k not in CONTEXT_CHOICES and k != "user")
json_values = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=10),
                           lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                                       max_size=4),
                           max_leaves=12)


def as_int(text: str) -> int | None:
    """What argparse's ``type=int`` makes of ``text`` (``None``: it refuses it)."""
    try:
        return int(text)
    except ValueError:
        return None


def is_user_name(value) -> bool:
    return isinstance(value, str) and value in NAMED_USERS


def names(field: str, message: str) -> bool:
    return repr(field) in message or f"{field}=" in message or f"{field} " in message


# ----- DriverProfile --------------------------------------------------------------------------------------
@FAST
@given(profile_values)
def test_profile_in_range_constructs_and_round_trips(values):
    p = DriverProfile(**values)
    assert all(isinstance(v, float) for v in p.to_dict().values())
    assert DriverProfile.from_dict(p.to_dict()) == p
    assert DriverProfile.from_dict(json.loads(json.dumps(p.to_dict()))) == p
    for name, v in values.items():
        assert getattr(p, name) == float(v)


@FAST
@given(st.data(), st.sampled_from(FIELD_NAMES))
def test_profile_out_of_range_names_field_and_range(data, name):
    value = data.draw(st.one_of(outside(name), NON_FINITE))
    lo, hi, _ = PROFILE_RANGES[name]
    for make in (lambda: DriverProfile(**{name: value}), lambda: DriverProfile.from_dict({name: value})):
        with pytest.raises(ProfileError) as err:
            make()
        assert f"{name}=" in str(err.value) and f"[{lo}, {hi}]" in str(err.value)


@FAST
@given(st.sampled_from(FIELD_NAMES), NOT_A_NUMBER)
def test_profile_wrong_type_names_field(name, value):
    with pytest.raises(ProfileError) as err:
        DriverProfile.from_dict({name: value})
    assert f"{name}=" in str(err.value)


@FAST
@given(profile_values, unknown_keys, st.integers())
def test_profile_unknown_field_is_named(values, key, value):
    with pytest.raises(ProfileError) as err:
        DriverProfile.from_dict({**values, key: value})
    assert repr(key) in str(err.value) and "allowed" in str(err.value)


@FAST
@given(st.one_of(st.lists(st.text(max_size=5), max_size=3), st.text(max_size=5), st.integers(), st.none()))
def test_profile_from_non_mapping_is_a_profile_error(data):
    with pytest.raises(ProfileError, match="mapping"):
        DriverProfile.from_dict(data)


# ----- load_user ------------------------------------------------------------------------------------------
@FAST
@given(profile_values, context_values, st.one_of(st.none(), st.sampled_from(sorted(NAMED_USERS))))
def test_load_user_valid_mappings(values, context, base):
    spec = {**values, **context, **({"user": base} if base else {})}
    profile, ctx = load_user(spec)
    expected = {**(NAMED_USERS[base] if base else DriverProfile()).to_dict(), **values}
    assert profile.to_dict() == {k: float(v) for k, v in expected.items()}
    assert ctx == (Context(**context) if context else None)


BAD_USER_FIELDS = st.one_of(
    st.tuples(st.just("profile"), st.sampled_from(FIELD_NAMES)),
    st.tuples(st.just("context"), st.sampled_from(list(CONTEXT_CHOICES))),
    st.tuples(st.just("unknown"), unknown_keys),
    st.tuples(st.just("user"), st.just("user")),
)


@FAST
@given(profile_values, context_values, BAD_USER_FIELDS, st.data())
def test_load_user_one_bad_key_is_named(values, context, bad, data):
    kind, key = bad
    spec = {**values, **context}
    if kind == "profile":
        spec[key] = data.draw(st.one_of(outside(key), NON_FINITE, NOT_A_NUMBER))
    elif kind == "context":
        spec[key] = data.draw(json_values.filter(lambda v: v not in CONTEXT_CHOICES[key]))
    elif kind == "unknown":
        spec[key] = data.draw(json_values)
    else:
        spec[key] = data.draw(json_values.filter(lambda v: not is_user_name(v) and v is not None))
    with pytest.raises(ProfileError) as err:
        load_user(spec)
    message = str(err.value)
    if kind == "unknown":
        assert repr(key) in message
    elif kind == "user":
        assert "unknown user" in message
    else:
        assert names(key, message)


@FAST
@given(st.one_of(json_values, st.text(max_size=300)))
def test_load_user_anything_is_a_profile_or_a_profile_error(spec):
    try:
        profile, ctx = load_user(spec)
    except ProfileError as exc:
        assert "\n" not in str(exc)
    else:
        assert isinstance(profile, DriverProfile) and (ctx is None or isinstance(ctx, Context))


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.one_of(st.text(max_size=200), json_values.map(json.dumps), json_values.map(yaml.safe_dump)),
       st.sampled_from([".json", ".yaml", ".yml"]))
def test_load_user_random_file_text(text, suffix):
    path = TMP / f"user{suffix}"
    path.write_text(text, errors="surrogatepass")
    try:
        load_user(str(path))
    except ProfileError as exc:
        assert "\n" not in str(exc)


@settings(max_examples=80, deadline=None, derandomize=True)
@given(st.sampled_from(["unknown", "route", "user", "context"]), st.data())
def test_reset_bad_options_raise_a_value_error_naming_them(which, data):
    """``NavigationEnv.reset(options=...)``: a bad option is a ValueError (TownError/ProfileError) that names
    it, raised before any world is built."""
    env = _env()
    if which == "unknown":
        key = data.draw(unknown_keys.filter(lambda k: k not in ("route", "context")))
        options, words = {key: data.draw(json_values)}, [repr(key)]
    elif which == "route":
        options = {"route": data.draw(json_values.filter(
            lambda v: not (isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 9)))}
        words = ["route"]
    elif which == "user":
        options = {"user": data.draw(json_values.filter(lambda v: not is_user_name(v) and not isinstance(v, dict)))}
        words = []
    else:
        ctx = data.draw(st.one_of(json_values.filter(lambda v: not isinstance(v, dict)),
                                  st.dictionaries(unknown_keys.filter(lambda k: isinstance(k, str)), json_values,
                                                  min_size=1),
                                  st.sampled_from(list(CONTEXT_CHOICES)).flatmap(lambda k: st.fixed_dictionaries(
                                      {k: json_values.filter(lambda v: v not in CONTEXT_CHOICES[k])}))))
        options, words = {"context": ctx}, []
    with pytest.raises(ValueError) as err:
        env.reset(seed=0, options=options)
    assert all(w in str(err.value) for w in words), str(err.value)


_ENV: list = []


def _env():
    if not _ENV:
        from pernav.env.navigation import NavigationEnv

        _ENV.append(NavigationEnv("Town1", config={"n_traffic": 0}))
    return _ENV[0]


# ----- schedules ------------------------------------------------------------------------------------------
LABEL = st.text(alphabet=string.ascii_letters + string.digits + " _-", min_size=1, max_size=10)
DRIVER = st.one_of(
    st.sampled_from(sorted(NAMED_USERS)),
    st.builds(lambda v, base: {**v, **({"user": base} if base else {})}, profile_values,
              st.one_of(st.none(), st.sampled_from(sorted(NAMED_USERS)))),
)


@st.composite
def schedules(draw) -> list[dict]:
    n_offline = draw(st.integers(1, 3))
    n_online = draw(st.integers(1, 4))
    labels = draw(st.lists(LABEL, min_size=n_offline + n_online, max_size=n_offline + n_online, unique=True))
    rows = []
    for i, label in enumerate(labels):
        row = {"label": label, "phase": "offline" if i < n_offline else "online", "driver": draw(DRIVER)}
        row.update(draw(context_values))
        if draw(st.booleans()):
            row["towns"] = draw(st.lists(st.sampled_from(TOWN_NAMES), min_size=1, max_size=5, unique=True))
        rows.append(row)
    return rows


@FAST
@given(schedules(), st.booleans())
def test_random_valid_schedules_parse(rows, wrapped):
    entries = parse_schedule({"schedule": rows} if wrapped else rows)
    assert [e.label for e in entries] == [r["label"] for r in rows]
    for e, r in zip(entries, rows, strict=True):
        assert e.phase == r["phase"]
        assert e.context() == Context(**{k: r[k] for k in CONTEXT_CHOICES if k in r})
        assert e.towns == (tuple(r["towns"]) if "towns" in r else None)
        assert isinstance(e.profile(), DriverProfile) and e.user()["profile"] == e.profile().to_dict()
    assert parse_schedule(json.loads(json.dumps([e.to_dict() for e in entries]))) == entries


CORRUPTIONS = ("unknown_field", "context", "phase", "town", "missing_driver", "duplicate_label", "not_mapping",
               "driver_value", "driver_name", "late_offline", "missing_label", "missing_phase")


@pytest.mark.slow
@FAST
@given(schedules(), st.sampled_from(CORRUPTIONS), st.data())
def test_one_corruption_names_entry_and_field(rows, kind, data):
    i = data.draw(st.integers(0, len(rows) - 1))
    row = rows[i]
    field = {"unknown_field": None, "phase": "phase", "town": "towns", "missing_driver": "driver",
             "duplicate_label": "label", "not_mapping": None, "driver_value": "driver", "driver_name": "driver",
             "late_offline": "phase", "missing_label": "label", "missing_phase": "phase"}.get(kind)
    if kind == "unknown_field":
        field = data.draw(unknown_keys.filter(lambda k: k not in FIELDS))  # noqa: B023 - drawn at once
        row[field] = data.draw(json_values)
    elif kind == "context":
        field = data.draw(st.sampled_from(list(CONTEXT_CHOICES)))
        row[field] = data.draw(json_values.filter(lambda v: v not in CONTEXT_CHOICES[field]))
    elif kind == "phase":
        row["phase"] = data.draw(json_values.filter(lambda v: v not in ("offline", "online")))
    elif kind == "town":
        bad = data.draw(json_values.filter(lambda v: v not in TOWN_NAMES))
        not_a_list = json_values.filter(lambda v: not isinstance(v, list) and v is not None)
        row["towns"] = data.draw(st.one_of(st.just([*row.get("towns", []), bad]), st.just([]), not_a_list))
    elif kind == "missing_driver":
        del row["driver"]
    elif kind == "duplicate_label":
        assume(i > 0)
        row["label"] = rows[data.draw(st.integers(0, i - 1))]["label"]
    elif kind == "not_mapping":
        rows[i] = data.draw(json_values.filter(lambda v: not isinstance(v, dict)))
    elif kind == "driver_value":
        name = data.draw(st.sampled_from(FIELD_NAMES))
        value = data.draw(st.one_of(outside(name), NON_FINITE, NOT_A_NUMBER))
        base = row["driver"] if isinstance(row["driver"], dict) else {"user": row["driver"]}
        row["driver"] = {**base, name: value}
    elif kind == "driver_name":
        row["driver"] = data.draw(json_values.filter(lambda v: not is_user_name(v) and not isinstance(v, dict)))
    elif kind == "late_offline":
        assume(row["phase"] == "online" and any(r["phase"] == "online" for r in rows[:i]))
        row["phase"] = "offline"
    elif kind == "missing_label":
        del row["label"]
    elif kind == "missing_phase":
        del row["phase"]
    with pytest.raises(ScheduleError) as err:
        parse_schedule(rows)
    message = str(err.value)
    assert re.match(rf"schedule entry {i}\b", message), message
    if field is not None:
        assert repr(field) in message, message
    if kind == "driver_value":
        assert f"{name}=" in message
    assert "\n" not in message


@FAST
@given(json_values)
def test_random_data_is_a_schedule_or_a_schedule_error(raw):
    try:
        parse_schedule(raw)
    except ScheduleError:
        pass


@settings(max_examples=100, deadline=None, derandomize=True)
@given(st.one_of(st.text(max_size=200), json_values.map(json.dumps), json_values.map(yaml.safe_dump),
                 schedules().map(yaml.safe_dump), st.binary(max_size=64)),
       st.sampled_from([".json", ".yaml", ".yml", ""]))
def test_random_schedule_files_raise_only_schedule_error(text, suffix):
    path = TMP / f"schedule{suffix or '.txt'}"
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, errors="surrogatepass")
    try:
        load_schedule(path)
    except ScheduleError as exc:
        assert "\n" not in str(exc)


@FAST
@given(st.text(max_size=300))
def test_missing_schedule_file_is_a_schedule_error(name):
    assume(not (TMP / "missing" / name).exists())
    with pytest.raises(ScheduleError):
        load_schedule(TMP / "missing" / name if name else TMP / "missing")


# ----- CLI ------------------------------------------------------------------------------------------------
def _never(*args, **kwargs):
    raise AssertionError("a bad input reached the simulation: validation let it through")


def run_cli(capsys, argv: list[str]) -> tuple[int, str]:
    """(exit code, stderr) of ``pernav argv``; the heavy work is patched to fail the test."""
    capsys.readouterr()
    with mock.patch("pernav.env.episodes.run_episode", _never), mock.patch("pernav.study.study.run_town", _never):
        try:
            code = main(argv)
            usage = False
        except SystemExit as exc:  # argparse's own usage errors
            code, usage = exc.code, True
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    if usage:
        assert lines and "error" in lines[-1], err
    else:
        assert len(lines) == 1 and "error" in lines[0], err
    return code, err


TEXT = st.text(max_size=20)
DRIVE = {"--town": "Town1", "--policy": "explore", "--user": "user1"}


def _bad_user_file(data) -> str:
    suffix = data.draw(st.sampled_from([".json", ".yaml"]))
    path = TMP / f"bad_user{suffix}"
    content = data.draw(st.one_of(
        st.text(max_size=50),
        st.fixed_dictionaries({"reaction_time": st.one_of(outside("reaction_time"), st.text(max_size=5))}).map(
            json.dumps),
        st.dictionaries(unknown_keys.filter(lambda k: isinstance(k, str)), st.integers(), min_size=1).map(
            json.dumps)))
    path.write_text(content)
    try:
        load_user(str(path))
    except ProfileError:
        return str(path)
    assume(False)


@CLI
@given(st.sampled_from(["town", "policy", "user", "routes", "context", "seed", "traffic", "gif", "user_file"]),
       st.data())
def test_cli_drive_bad_values_exit_2(capsys, which, data):
    args = dict(DRIVE)
    extra: list[str] = []
    if which == "town":
        args["--town"] = data.draw(TEXT.filter(lambda t: t not in TOWN_NAMES))
    elif which == "policy":
        args["--policy"] = data.draw(TEXT.filter(lambda t: t not in ("explore", "oracle")))
    elif which == "user":
        args["--user"] = data.draw(st.text(max_size=300).filter(lambda t: t not in NAMED_USERS))
    elif which == "user_file":
        args["--user"] = _bad_user_file(data)
    elif which == "routes":
        bad = data.draw(st.one_of(st.integers(max_value=-1).map(str), st.integers(min_value=10).map(str),
                                  TEXT.filter(lambda t: as_int(t) is None or not 0 <= as_int(t) <= 9)))
        extra = ["--routes", *data.draw(st.lists(st.integers(0, 9).map(str), max_size=2)), bad]
    elif which == "context":
        key = data.draw(st.sampled_from(list(CONTEXT_CHOICES)))
        extra = [f"--{key}", data.draw(TEXT.filter(lambda t: t not in CONTEXT_CHOICES[key]))]
    elif which == "seed":
        extra = ["--seed", data.draw(st.one_of(st.integers(max_value=-1).map(str), TEXT.filter(
            lambda t: as_int(t) is None or as_int(t) < 0)))]
    elif which == "traffic":
        extra = ["--traffic", str(data.draw(st.one_of(st.integers(max_value=-1),
                                                      st.integers(min_value=MAX_TRAFFIC + 1))))]
    elif which == "gif":
        extra = ["--gif", data.draw(st.one_of(
            st.just(str(TMP / "no-such-folder" / "x.gif")),
            TEXT.filter(lambda t: t and not t.startswith("-") and not t.lower().endswith(".gif"))))]
    argv = ["drive", *[x for kv in args.items() for x in kv], *extra]
    code, err = run_cli(capsys, argv)
    assert code == 2


@CLI
@given(st.sampled_from(["preset", "workers", "schedule", "towns", "seed"]), st.data())
def test_cli_study_bad_values_exit_2(capsys, which, data):
    out = TMP / "study-out"
    args = {"--preset": "smoke", "--out": str(out)}
    extra: list[str] = []
    if which == "preset":
        args["--preset"] = data.draw(TEXT.filter(lambda t: t not in PRESETS))
    elif which == "workers":
        extra = ["--workers", str(data.draw(st.integers(max_value=0)))]
    elif which == "schedule":
        name = data.draw(st.text(alphabet=string.ascii_letters + string.digits + "._-", min_size=1, max_size=30))
        extra = ["--schedule", str(TMP / "no-such-folder" / name)]
    elif which == "towns":
        good = data.draw(st.lists(st.sampled_from(TOWN_NAMES), max_size=2))
        extra = ["--towns", *good, data.draw(TEXT.filter(lambda t: t not in TOWN_NAMES))]
    elif which == "seed":
        extra = ["--seed", data.draw(TEXT.filter(lambda t: as_int(t) is None))]
    argv = ["study", *[x for kv in args.items() for x in kv], *extra]
    code, err = run_cli(capsys, argv)
    assert code == 2
    assert not out.exists() or not any(out.iterdir())  # nothing written


@CLI
@given(st.sampled_from(["holds_study", "not_empty", "is_file"]), st.booleans(), st.binary(max_size=20))
def test_cli_study_never_overwrites(capsys, kind, resume, precious):
    out = TMP / f"occupied-{kind}"
    if kind == "is_file":
        out.write_bytes(precious)
        before = {out.name: precious}
    else:
        out.mkdir(exist_ok=True)
        for p in out.iterdir():
            p.unlink()
        (out / "results.json").write_bytes(precious)
        if kind == "holds_study":
            (out / "study.json").write_text(json.dumps({"preset": "another"}))
        before = {p.name: p.read_bytes() for p in out.iterdir()}
    argv = ["study", "--preset", "smoke", "--out", str(out), *(["--resume"] if resume else [])]
    code, err = run_cli(capsys, argv)
    assert code == 2
    after = {out.name: out.read_bytes()} if out.is_file() else {p.name: p.read_bytes() for p in out.iterdir()}
    assert after == before


@CLI
@given(st.one_of(
    st.tuples(st.just("towns"), st.just("--towns"), TEXT.filter(lambda t: t not in TOWN_NAMES)),
    st.tuples(st.just("towns"), st.just("--out"), st.just("file")),
    st.tuples(st.just("bench"), st.just("which"), TEXT.filter(lambda t: t not in ("sim", "planner", "train", "play", "all")
                                                             and not t.startswith("-"))),
    st.tuples(st.just("bench"), st.just("--flag"), st.sampled_from(["--nope", "--quick=1", "--json=yes"])),
    st.tuples(st.just("command"), st.just(""), TEXT.filter(lambda t: t not in ("towns", "drive", "bench", "study", "play",
                                                                           "personalize")
                                                           and not t.startswith("-"))),
))
def test_cli_other_commands_bad_values_exit_2(capsys, case):
    command, option, value = case
    if command == "towns" and option == "--out":
        target = TMP / "a-file.png"
        target.write_text("precious")
        argv = ["towns", "--out", str(target)]
    elif command == "towns":
        argv = ["towns", "--out", str(TMP / "maps"), "--towns", value]
    elif option == "which":
        argv = ["bench", value]
    elif command == "bench":
        argv = ["bench", value]
    else:
        argv = [value] if value else []
    code, err = run_cli(capsys, argv)
    assert code == 2
    if option == "--out":
        assert (TMP / "a-file.png").read_text() == "precious"

"""Run settings: what a user may set, how command-line text becomes values, and checking them before any run.

A setting is ``policy``, a keyword argument of the environment (read from its signature, so a new env argument
is settable without touching this module) or a reset option (``slew_angle_deg``, ``slew_axis_body``,
``q_target``). Values are read as JSON where they are not plain words, so lists (``[5,6,4]``) and fault
schedules (``[{"kind": "dropout", ...}]``) can be given on the command line.
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import json
import math
import os
import sys

import numpy as np

__all__ = [
    "ENV_IDS_BY_TASK", "RESET_KEYS", "env_keys", "setting_keys", "parse_value", "parse_values", "check_setting_keys",
    "split_settings", "resolve_env_config", "validate_settings", "ensure_working_directory_importable",
]

ENV_IDS_BY_TASK = {"slew": "startracker/AgileSlew-v0", "hold": "startracker/AttitudeHold-v0"}
# options of AgileSlewEnv.reset that a run may fix (``faults`` is also an env argument, which is used instead)
RESET_KEYS = ("slew_angle_deg", "slew_axis_body", "q_target")
_NOT_SETTINGS = ("self", "render_mode")


def env_keys() -> tuple[str, ...]:
    """The environment's keyword arguments (from ``AgileSlewEnv.__init__``), without ``render_mode``."""
    from envs.agile_slew import AgileSlewEnv

    return tuple(n for n in inspect.signature(AgileSlewEnv.__init__).parameters if n not in _NOT_SETTINGS)


def setting_keys() -> tuple[str, ...]:
    """Every key a campaign grid or ``--env`` may set: ``policy``, the env arguments and the reset options."""
    return ("policy",) + env_keys() + RESET_KEYS


def parse_value(text: str):
    """One value from the command line: JSON if it parses (numbers, lists, objects, true/false), else the text."""
    text = text.strip()
    try:
        return json.loads(text)
    except ValueError:
        pass
    parts = _split_top_level(text)
    if len(parts) > 1:  # 10,10,10 -> [10, 10, 10]
        return [parse_value(p) for p in parts]
    return text


def parse_values(text: str) -> list:
    """A grid's value list ``v1,v2,...``; commas inside brackets or quotes belong to a value (``[5,6,4],[1,1,1]``)."""
    text = text.strip()
    try:
        vals = json.loads(f"[{text}]")
        return vals
    except ValueError:
        pass
    out = []
    for p in _split_top_level(text):
        p = p.strip()
        if p:
            try:
                out.append(json.loads(p))
            except ValueError:
                out.append(p)
    return out


def _split_top_level(text: str) -> list[str]:
    parts, depth, cur, quote = [], 0, [], None
    for ch in text:
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "[{(":
            depth += 1
        elif ch in "]})":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append("".join(cur))
            cur = []
            continue
        cur.append(ch)
    parts.append("".join(cur))
    return parts


def check_setting_keys(keys, what: str = "setting") -> None:
    """ValueError naming the first unknown key, with the closest known one."""
    known = setting_keys()
    for k in keys:
        if k not in known:
            near = difflib.get_close_matches(k, known, n=1)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise ValueError(f"unknown {what} {k!r}{hint}; allowed: {', '.join(known)}")


def split_settings(settings: dict) -> tuple[str, str, dict, dict]:
    """``settings`` -> (env id, policy, env keyword arguments, reset options)."""
    s = dict(settings)
    policy = s.pop("policy", "eigenaxis")
    task = s.pop("task", "slew")
    if task not in ENV_IDS_BY_TASK:
        raise ValueError(f"task must be one of {sorted(ENV_IDS_BY_TASK)}, got {task!r}")
    options = {k: s.pop(k) for k in RESET_KEYS if k in s}
    if "slew_angle_deg" in options:
        a = options["slew_angle_deg"]
        if isinstance(a, bool) or not isinstance(a, (int, float)) or not math.isfinite(a) or not 0.0 <= a <= 180.0:
            raise ValueError(f"slew_angle_deg must be a number in [0, 180] deg, got {a!r}")
        options["slew_angle_deg"] = float(a)
    env_id = ENV_IDS_BY_TASK[task]
    if task == "slew" and isinstance(policy, str):
        from policies import policy_env

        # a trained policy runs on the env it was trained for (its id and the arguments of its action space)
        trained_id, interface = policy_env(policy)
        if trained_id != env_id:
            env_id, s = trained_id, {**interface, **s}
    return env_id, str(policy), s, options


def resolve_env_config(env_id: str, env_kwargs: dict, env=None) -> dict:
    """Every env argument with the value the run uses: the signature's default, the id's registered default, the
    user's value. Arguments the env resolves itself (``None`` defaults such as the disturbance torque) are read back
    from a constructed ``env`` when one is given."""
    import gymnasium as gym
    from envs.agile_slew import AgileSlewEnv

    from experiments.telemetry import to_jsonable

    sig = inspect.signature(AgileSlewEnv.__init__).parameters
    cfg = {k: p.default for k, p in sig.items() if k not in _NOT_SETTINGS}
    cfg.update(gym.spec(env_id).kwargs)
    cfg.update(env_kwargs)
    if env is not None:
        u = env.unwrapped
        for k, v in cfg.items():
            if v is None and hasattr(u, k):
                cfg[k] = getattr(u, k)
        if hasattr(u, "fault_list"):  # each fault with its default severity filled in
            cfg["faults"] = list(u.fault_list)
    if cfg.get("faults") is not None:
        cfg["faults"] = [dataclasses.asdict(f) if dataclasses.is_dataclass(f) else f for f in cfg["faults"]]
    return to_jsonable(cfg)


def validate_settings(settings: dict) -> dict:
    """Check one run's settings by building its policy class and its env once; return the resolved env config.

    Raises
    ------
    ValueError
        Naming the setting: unknown keys, a policy that cannot be loaded, any value the env refuses.
    """
    import gymnasium as gym

    import envs  # noqa: F401  (registers the ids)
    from policies import load_policy

    check_setting_keys(settings)
    env_id, policy, kwargs, _ = split_settings(settings)
    ensure_working_directory_importable()
    load_policy(policy)
    try:
        env = gym.make(env_id, **kwargs)
    except (ValueError, TypeError) as exc:
        shown = ", ".join(f"{k}={json.dumps(v, default=str)}" for k, v in sorted(kwargs.items()))
        raise ValueError(f"{exc} (settings: {shown or 'defaults'})") from None
    try:
        return resolve_env_config(env_id, kwargs, env)
    finally:
        env.close()


def ensure_working_directory_importable() -> None:
    """Put the working directory first on ``sys.path``, as ``python -m`` does, so ``--policy mymodule:MyPD``
    finds the user's own module (a console script starts with only its own folder on the path)."""
    cwd = os.getcwd()
    if cwd not in sys.path and "" not in sys.path:
        sys.path.insert(0, cwd)


def as_scalar_text(value) -> str:
    """A setting value as it appears in tables and CSV columns: scalars as they are, others as compact JSON."""
    if isinstance(value, (str, int, float, bool)) or value is None:
        return str(value)
    if isinstance(value, np.ndarray):
        value = value.tolist()
    return json.dumps(value, separators=(",", ":"), sort_keys=True, default=str)

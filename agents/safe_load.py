"""Loading saved agents without running code from the files.

Why this module exists: stable-baselines3's ``BaseAlgorithm.load`` cloudpickle-loads every entry of
the zip's ``data`` JSON that carries a ``:serialized:`` field (spaces, schedules, the policy class,
buffers), and ``VecNormalize.load`` is a plain ``pickle.load``: a crafted model file runs code the
moment it is loaded. SB3's public ``custom_objects`` argument replaces an entry *before* it is
deserialised, so :func:`load_sb3_model` rebuilds every entry SB3 writes for our agents from the
model's sidecar (its recipe and agent spec) and passes them in; nothing of ``data`` is unpickled.
The weights (``*.pth`` members) are checked here with ``torch.load(weights_only=True)``, torch's
restricted unpickler, whatever SB3 itself does with them. A file with any other serialised entry
(one we cannot rebuild) is refused, naming the file and the entry, unless the caller passes
``trust_model=True`` (the CLI's ``--trust-model``): then SB3's own loader runs unchanged, code in
the file included.

The entries rebuilt are cross-checked against the plain-text description SB3 writes beside each
serialised value (network sizes, activation, schedule constants, space shape), so a sidecar that
does not describe its model is an error instead of a silently different agent.

VecNormalize statistics are kept as JSON (``NAME.vecnormalize.json``: running means, variances,
counts, clip, gamma, epsilon), written by :func:`save_vecnormalize` and read back into a fresh
``VecNormalize`` by :func:`load_vecnormalize` through its public attributes.

The models shipped in ``agents/models`` are listed with their SHA-256 digests in
``agents/models/MANIFEST.json``; :func:`verify_shipped` checks a shipped model's files against it
before anything of them is used (a changed file is an error: it is no longer the model we ship).
"""
from __future__ import annotations

import hashlib
import io
import json
import pickle
import warnings
import zipfile
from collections import deque
from pathlib import Path
from typing import Any, Callable, Mapping

from wt_inspect_env.util.atomic_io import write_text_atomic

MODELS_DIR = Path(__file__).resolve().parent / "models"
MANIFEST_NAME = "MANIFEST.json"
MANIFEST_FORMAT = 1
VECNORM_SUFFIX = ".vecnormalize.json"
VECNORM_FORMAT = 1
LEGACY_VECNORM_SUFFIX = ".vecnormalize.pkl"
_ACTIVATION_CLASSES: dict[str, str] = {"tanh": "Tanh", "relu": "ReLU", "elu": "ELU", "leaky_relu": "LeakyReLU"}
ACTIVATIONS: tuple[str, ...] = tuple(_ACTIVATION_CLASSES)   # the names a recipe may give (torch.nn classes)
TRUST_HINT = "pass --trust-model (trust_model=True) only if you trust whoever made the file: it runs code from it"

def shipped_models() -> list[str]:
    """Names of the models shipped in ``agents/models`` (``ppo:NAME`` loads one)."""
    return sorted(p.stem for p in MODELS_DIR.glob("*.zip"))


def resolve_model_path(arg: str) -> Path:
    """``arg`` as a model file: a path to an existing file, or the name of a shipped model
    (``ppo_surface`` -> ``agents/models/ppo_surface.zip``)."""
    p = Path(arg)
    if p.is_file():
        return p
    if p.suffix != ".zip" and len(p.parts) == 1 and (MODELS_DIR / f"{arg}.zip").is_file():
        return MODELS_DIR / f"{arg}.zip"
    raise ValueError(f"model {arg!r} is neither a file nor a shipped model; shipped: {', '.join(shipped_models())}")


class UnsafeModelError(ValueError):
    """A model file that could only be loaded by running code from it (unpickling)."""


# ------------------------------------------------------------------ recipe -> SB3 arguments
def sb3_policy_kwargs(policy_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """A recipe's ``policy_kwargs`` as SB3 takes them (the activation name -> its torch class)."""
    import torch.nn as nn
    kw = dict(policy_kwargs)
    act = kw.get("activation_fn")
    if act is not None:
        if act not in _ACTIVATION_CLASSES:
            raise ValueError(f"policy_kwargs activation_fn must be one of {', '.join(ACTIVATIONS)}, got {act!r}")
        kw["activation_fn"] = getattr(nn, _ACTIVATION_CLASSES[act])
    return kw


def sb3_algo_kwargs(algo_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """A recipe's ``algo_kwargs`` as SB3 takes them (``learning_rate_final`` -> a linear schedule)."""
    from stable_baselines3.common.utils import LinearSchedule
    kw = dict(algo_kwargs)
    final = kw.pop("learning_rate_final", None)
    if final is not None:
        lr0 = float(kw.get("learning_rate", 3e-4))
        kw["learning_rate"] = LinearSchedule(lr0, float(final), 1.0)
    return kw


# ------------------------------------------------------------------ the zip's data entries
def _is_serialized(value: Any) -> bool:
    return isinstance(value, dict) and ":serialized:" in value


def read_data(zip_path: str | Path) -> dict[str, Any]:
    """The ``data`` JSON of a SB3 zip as it is stored (nothing deserialised)."""
    p = Path(zip_path)
    try:
        with zipfile.ZipFile(p) as z:
            if "data" not in z.namelist():
                raise ValueError(f"model file {str(p)!r} has no 'data' member (not a stable-baselines3 model)")
            doc = json.loads(z.read("data").decode())
    except zipfile.BadZipFile:
        raise ValueError(f"model file {str(p)!r} is not a zip archive (not a stable-baselines3 model)") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"model file {str(p)!r}: its 'data' member is not valid JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"model file {str(p)!r}: its 'data' member is not a JSON object")
    return doc


def serialized_entries(zip_path: str | Path) -> dict[str, dict[str, Any]]:
    """The entries of a SB3 zip's ``data`` that SB3 would unpickle, with SB3's plain-text
    description of each (every key but ``:serialized:``). Reads JSON only."""
    return {k: {kk: vv for kk, vv in v.items() if kk != ":serialized:"}
            for k, v in read_data(zip_path).items() if _is_serialized(v)}


def _describe(obj: Any) -> dict[str, Any]:
    """SB3's plain-text description of a value it serialises (``save_util.data_to_json``)."""
    def plain(v: Any) -> Any:
        try:
            return json.loads(json.dumps(v))   # as read back from the file (tuples become lists)
        except (TypeError, ValueError):
            return str(v)
    items = obj.items() if isinstance(obj, dict) else getattr(obj, "__dict__", {}).items()
    return {":type:": str(type(obj)), **{k: plain(v) for k, v in items}}


# which description keys must agree between the file and the rebuilt object
_COMPARED: dict[str, tuple[str, ...] | None] = {
    "policy_class": (":type:", "__module__"),
    "policy_kwargs": None,                     # None: every key
    "observation_space": (":type:", "dtype", "_shape", "low", "high"),
    "action_space": (":type:", "dtype", "_shape", "low", "high"),
    "learning_rate": None,
    "lr_schedule": (":type:", "value_schedule"),
    "clip_range": (":type:", "value_schedule"),
    "clip_range_vf": (":type:", "value_schedule"),
    "train_freq": (":type:",),
    "_last_obs": (), "_last_episode_starts": (), "_last_original_obs": (),
    "ep_info_buffer": (), "ep_success_buffer": (),
    "rollout_buffer_class": (), "replay_buffer_class": (),
}


def _rebuilders(cls: type, doc: Mapping[str, Any], data: Mapping[str, Any]) -> dict[str, Callable[[], Any]]:
    """How to rebuild each entry SB3 serialises for our PPO / SAC agents, from the sidecar (and
    the file's plain entries: a learning rate stored as a number is that number)."""
    import numpy as np
    from gymnasium import spaces
    from stable_baselines3.common.utils import FloatSchedule

    from .wrappers import AgentSpec

    spec = AgentSpec.from_dict(doc["spec"])
    recipe = doc.get("recipe")

    def from_recipe(section: str) -> dict[str, Any]:
        if not isinstance(recipe, Mapping) or not isinstance(recipe.get(section, {}), Mapping):
            raise LookupError(section)
        return dict(recipe.get(section, {}))

    def algo_kw() -> dict[str, Any]:
        return sb3_algo_kwargs(from_recipe("algo_kwargs"))

    def lr() -> Any:
        stored = data.get("learning_rate")
        if isinstance(stored, (int, float)) and not isinstance(stored, bool):
            return float(stored)
        return algo_kw().get("learning_rate", 3e-4)

    def schedule(name: str, default: Any) -> Callable[[], Any]:
        def build() -> Any:
            value = algo_kw().get(name, default)
            return None if value is None else FloatSchedule(value)
        return build

    c = float(spec.features.clip)
    n = spec.features.size
    return {
        "policy_class": lambda: cls.policy_aliases["MlpPolicy"],
        "policy_kwargs": lambda: sb3_policy_kwargs(from_recipe("policy_kwargs")),
        "observation_space": lambda: spaces.Box(-c, c, shape=(n,), dtype=np.float32),
        "action_space": lambda: spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32),
        "learning_rate": lr,
        "lr_schedule": lambda: FloatSchedule(lr()),
        "clip_range": schedule("clip_range", 0.2),
        "clip_range_vf": schedule("clip_range_vf", None),
        "train_freq": lambda: algo_kw().get("train_freq", 1),   # SB3's _setup_model makes the TrainFreq
        # state of the last rollout: SB3 starts a fresh one when training resumes
        "_last_obs": lambda: None, "_last_episode_starts": lambda: None, "_last_original_obs": lambda: None,
        "ep_info_buffer": lambda: deque(maxlen=100), "ep_success_buffer": lambda: deque(maxlen=100),
        # None: SB3 picks its default buffer for the observation space, as it did at training
        "rollout_buffer_class": lambda: None, "replay_buffer_class": lambda: None,
    }


def rebuild_custom_objects(cls: type, zip_path: str | Path, doc: Mapping[str, Any]) -> dict[str, Any]:
    """``custom_objects`` for ``cls.load(zip_path)`` replacing every entry SB3 would unpickle.

    UnsafeModelError naming the file and the entry if one cannot be rebuilt (unknown entry, no
    recipe in the sidecar); ValueError if a rebuilt entry disagrees with the file's description.
    """
    p = str(zip_path)
    data = read_data(zip_path)
    builders = _rebuilders(cls, doc, data)
    out: dict[str, Any] = {}
    entries = {k: {kk: vv for kk, vv in v.items() if kk != ":serialized:"}
               for k, v in data.items() if _is_serialized(v)}
    for name, described in entries.items():
        if name not in builders:
            raise UnsafeModelError(f"model file {p!r}: entry {name!r} of its data would need unpickling "
                                   f"(type {described.get(':type:', '?')}) and cannot be rebuilt from the sidecar; "
                                   f"{TRUST_HINT}")
        try:
            obj = builders[name]()
        except LookupError as exc:
            raise UnsafeModelError(f"model file {p!r}: entry {name!r} of its data would need unpickling and the "
                                   f"sidecar has no recipe {exc.args[0]!r} to rebuild it from; {TRUST_HINT}") from None
        mine = _describe(obj) if obj is not None else {}
        keys = _COMPARED[name]
        for key in (described if keys is None else keys):
            if key in described and key in mine and described[key] != mine[key]:
                raise ValueError(f"model file {p!r}: entry {name!r} does not match its sidecar: {key} is "
                                 f"{described[key]!r} in the file, {mine[key]!r} from the sidecar")
        out[name] = obj
    return out


def check_weights_only(zip_path: str | Path) -> None:
    """ValueError naming the member unless every ``*.pth`` of the zip loads with torch's
    weights-only unpickler (tensors and plain containers; no code)."""
    import torch
    with zipfile.ZipFile(zip_path) as z:
        for member in z.namelist():
            if member.endswith(".pth"):
                try:
                    torch.load(io.BytesIO(z.read(member)), map_location="cpu", weights_only=True)
                except (pickle.UnpicklingError, RuntimeError, EOFError, AttributeError, TypeError) as exc:
                    first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                    raise UnsafeModelError(f"model file {str(zip_path)!r}: member {member!r} is not a weights-only "
                                           f"torch file ({first}); {TRUST_HINT}") from None


# Entries of a SB3 zip's ``data`` its loader needs before anything else (the policy to build, the
# spaces to check an env against): a file without them is no model, whatever else it holds.
REQUIRED_DATA = ("policy_class", "observation_space", "action_space")


def check_model_data(zip_path: str | Path) -> dict[str, Any]:
    """The zip's ``data`` (as stored), or ValueError naming the file and the first missing entry of
    :data:`REQUIRED_DATA` (a ``data`` of ``{}`` would otherwise be SB3's bare KeyError)."""
    data = read_data(zip_path)
    missing = [k for k in REQUIRED_DATA if k not in data]
    if missing:
        raise ValueError(f"model file {str(zip_path)!r}: its data has no {missing[0]!r} entry (a stable-baselines3 "
                         f"model stores {', '.join(REQUIRED_DATA)}); not a model saved by wt-inspect train")
    return data


def check_safe(cls: type, zip_path: str | Path, doc: Mapping[str, Any]) -> dict[str, Any]:
    """Everything :func:`load_sb3_model` checks before loading; returns the ``custom_objects``."""
    check_model_data(zip_path)
    objects = rebuild_custom_objects(cls, zip_path, doc)
    check_weights_only(zip_path)
    return objects


def load_sb3_model(cls: type, zip_path: str | Path, doc: Mapping[str, Any], *, trust_model: bool = False,
                   **load_kwargs: Any) -> Any:
    """``cls.load(zip_path, **load_kwargs)`` without unpickling anything from the file (see the
    module docstring); with ``trust_model`` SB3's own loader runs (a warning says so)."""
    verify_shipped(zip_path)
    if trust_model:
        check_model_data(zip_path)
        warnings.warn(f"--trust-model: loading {str(zip_path)!r} with stable-baselines3's pickle-based loader; "
                      "code in the file runs", stacklevel=2)
        return _sb3_load(cls, zip_path, load_kwargs)
    objects = check_safe(cls, zip_path, doc)
    return _sb3_load(cls, zip_path, {"custom_objects": objects, **load_kwargs})


def _sb3_load(cls: type, zip_path: str | Path, kwargs: Mapping[str, Any]) -> Any:
    """``cls.load``; a ``data`` entry SB3 expects but the file lacks (KeyError / AttributeError
    from its set-up) is a ValueError naming the file and the entry."""
    try:
        return cls.load(str(zip_path), **kwargs)
    except (KeyError, AttributeError) as exc:
        what = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
        raise ValueError(f"model file {str(zip_path)!r} is not a loadable {cls.__name__} model: its data lacks or "
                         f"mangles {what!r}") from None


def load_legacy_vecnormalize(path: str | Path, venv: Any) -> Any:
    """A training ``VecNormalize`` around ``venv`` from an old pickled ``NAME.vecnormalize.pkl``.
    UNSAFE - unpickling runs code from the file: only behind ``--trust-model``. What SB3's
    ``VecNormalize.load`` does, plus a ValueError naming the file when the pickle is not
    VecNormalize statistics (instead of an AttributeError from ``set_venv``)."""
    from stable_baselines3.common.vec_env import VecNormalize

    p = Path(path)
    try:
        with open(p, "rb") as fh:
            obj = pickle.load(fh)   # noqa: S301 - trusted by the caller (--trust-model)
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError, IndexError, TypeError,
            ValueError) as exc:
        raise ValueError(f"normalisation statistics {str(p)!r} cannot be unpickled: {exc}") from None
    if not isinstance(obj, VecNormalize):
        raise ValueError(f"normalisation statistics {str(p)!r} hold a {type(obj).__module__}.{type(obj).__name__}, "
                         "not VecNormalize statistics")
    try:
        obj.set_venv(venv)
    except (ValueError, AttributeError, KeyError, AssertionError) as exc:   # statistics of another env
        raise ValueError(f"normalisation statistics {str(p)!r} do not fit this environment: {exc}") from None
    obj.training = True
    return obj


# ------------------------------------------------------------------ VecNormalize as JSON
def vecnormalize_path(stem: str | Path) -> Path:
    """The JSON file of the VecNormalize statistics that belongs to the model saved as ``stem``."""
    return Path(str(stem) + VECNORM_SUFFIX)


def save_vecnormalize(vecnormalize: Any, path: str | Path) -> Path:
    """The statistics and switches of a (Box-observation) ``VecNormalize`` as JSON (exact: floats
    round-trip through JSON)."""
    def rms(r: Any) -> dict[str, Any]:
        import numpy as np
        return {"mean": np.asarray(r.mean, dtype=float).tolist(), "var": np.asarray(r.var, dtype=float).tolist(),
                "count": float(r.count)}
    if isinstance(vecnormalize.obs_rms, dict):
        raise ValueError("VecNormalize with Dict observations is not supported (the agents see a flat Box)")
    doc = {"format": VECNORM_FORMAT, "norm_obs": bool(vecnormalize.norm_obs),
           "norm_reward": bool(vecnormalize.norm_reward), "clip_obs": float(vecnormalize.clip_obs),
           "clip_reward": float(vecnormalize.clip_reward), "gamma": float(vecnormalize.gamma),
           "epsilon": float(vecnormalize.epsilon), "obs_rms": rms(vecnormalize.obs_rms),
           "ret_rms": rms(vecnormalize.ret_rms)}
    write_text_atomic(Path(path), json.dumps(doc, indent=1))
    return Path(path)


def load_vecnormalize(path: str | Path, venv: Any) -> Any:
    """A training ``VecNormalize`` around ``venv`` with the statistics of ``path`` (written by
    :func:`save_vecnormalize`); ValueError naming the file and field for anything malformed."""
    import numpy as np
    from stable_baselines3.common.vec_env import VecNormalize

    p = Path(path)
    verify_shipped(p)
    try:
        doc = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"normalisation statistics {str(p)!r} cannot be read as JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != VECNORM_FORMAT:
        raise ValueError(f"normalisation statistics {str(p)!r}: format must be {VECNORM_FORMAT}, "
                         f"got {doc.get('format') if isinstance(doc, dict) else doc!r}")
    n = int(np.prod(venv.observation_space.shape))

    def number(key: str) -> float:
        v = doc.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            raise ValueError(f"normalisation statistics {str(p)!r}: {key} must be a finite number, got {v!r}")
        return float(v)

    def rms(key: str, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, float]:
        r = doc.get(key)
        if not isinstance(r, dict):
            raise ValueError(f"normalisation statistics {str(p)!r}: {key} must be an object, got {r!r}")
        try:
            mean = np.asarray(r["mean"], dtype=np.float64).reshape(shape)
            var = np.asarray(r["var"], dtype=np.float64).reshape(shape)
            count = float(r["count"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"normalisation statistics {str(p)!r}: {key} must hold mean/var of shape {shape} "
                             f"and a count ({exc})") from None
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(var)) and np.all(var >= 0) and count > 0):
            raise ValueError(f"normalisation statistics {str(p)!r}: {key} has non-finite or negative values")
        return mean, var, count

    for key in ("norm_obs", "norm_reward"):
        if not isinstance(doc.get(key), bool):
            raise ValueError(f"normalisation statistics {str(p)!r}: {key} must be true or false, got {doc.get(key)!r}")
    obs = rms("obs_rms", tuple(venv.observation_space.shape)) if n else None
    ret = rms("ret_rms", ())
    vn = VecNormalize(venv, training=True, norm_obs=doc["norm_obs"], norm_reward=doc["norm_reward"],
                      clip_obs=number("clip_obs"), clip_reward=number("clip_reward"), gamma=number("gamma"),
                      epsilon=number("epsilon"))
    if obs is not None:
        vn.obs_rms.mean, vn.obs_rms.var, vn.obs_rms.count = obs
    vn.ret_rms.mean, vn.ret_rms.var, vn.ret_rms.count = float(ret[0]), float(ret[1]), ret[2]
    return vn


# ------------------------------------------------------------------ shipped models' digests
def sha256_file(path: str | Path) -> str:
    """SHA-256 of a file's bytes (hex), read in blocks (models can be large)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _model_files(stem: Path) -> list[Path]:
    """The files a model is loaded from (the zip, the sidecar, the normalisation statistics)."""
    return [stem.with_suffix(".zip"), stem.with_suffix(".json"), vecnormalize_path(stem)]


def _stem(path: str | Path) -> Path:
    p = Path(path)
    name = p.name
    for suffix in (VECNORM_SUFFIX, LEGACY_VECNORM_SUFFIX, ".zip", ".json"):
        if name.endswith(suffix):
            return p.with_name(name[: -len(suffix)])
    return p


def verify_shipped(path: str | Path, models_dir: Path | None = None) -> None:
    """For a model in ``models_dir`` (default: the shipped models' directory): ValueError naming
    the file unless each of its files is listed in the manifest with the same SHA-256. Other
    paths: nothing to check."""
    models_dir = MODELS_DIR if models_dir is None else Path(models_dir)
    stem = _stem(path)
    try:
        if stem.resolve().parent != models_dir.resolve():
            return
    except OSError:
        return
    manifest = models_dir / MANIFEST_NAME
    try:
        listed = json.loads(manifest.read_text())["files"]
    except (OSError, KeyError, TypeError, json.JSONDecodeError) as exc:
        raise ValueError(f"shipped-model manifest {str(manifest)!r} is missing or unreadable ({exc}); "
                         "reinstall the package") from None
    for f in _model_files(stem):
        want = listed.get(f.name)
        if want is None:
            required = f.suffix == ".zip" or f.name == stem.name + ".json"
            if required or f.exists():
                raise ValueError(f"shipped model file {str(f)!r} is not listed in {str(manifest)!r} "
                                 "(not a model we ship); copy it elsewhere to load it as your own file")
            continue
        if not f.is_file():
            raise ValueError(f"shipped model file {str(f)!r} is missing (listed in {str(manifest)!r}); "
                             "reinstall the package")
        have = sha256_file(f)
        if have != want:
            raise ValueError(f"shipped model file {str(f)!r} has SHA-256 {have[:16]}..., the manifest says "
                             f"{want[:16]}...: the file was changed; reinstall the package")


def write_manifest(models_dir: Path | None = None) -> Path:
    """(Re)write ``models_dir/MANIFEST.json`` (default: the shipped models') with the digest of
    every model's files - run after adding or retraining a shipped model."""
    models_dir = MODELS_DIR if models_dir is None else Path(models_dir)
    files = {}
    for z in sorted(models_dir.glob("*.zip")):
        for f in _model_files(z.with_suffix("")):
            if f.is_file():
                files[f.name] = sha256_file(f)
    path = models_dir / MANIFEST_NAME
    write_text_atomic(path, json.dumps({"format": MANIFEST_FORMAT, "algorithm": "sha256", "files": files},
                                       indent=1) + "\n")
    return path


__all__ = ["UnsafeModelError", "load_sb3_model", "check_safe", "check_model_data", "load_legacy_vecnormalize",
           "rebuild_custom_objects", "serialized_entries", "read_data",
           "check_weights_only", "save_vecnormalize", "load_vecnormalize", "vecnormalize_path", "verify_shipped",
           "write_manifest", "sha256_file", "sb3_policy_kwargs", "sb3_algo_kwargs", "MODELS_DIR", "TRUST_HINT"]

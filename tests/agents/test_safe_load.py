"""Model files run no code when loaded (issue 17): crafted ``:serialized:`` entries and ``.pth``
members are refused without ``trust_model`` (and their payload never runs), entries SB3 would
unpickle are rebuilt from the sidecar, shipped models are digest-checked, the VecNormalize
statistics are JSON, and the converted shipped models act as before the conversion (to float32 rounding).

The crafted payload is a pickle whose ``__reduce__`` writes a marker file; each "refused" test
asserts the marker does not exist, and one test loads the same file with ``trust_model=True`` to
show the payload does run then (so the "not written" assertions can fail).
"""
from __future__ import annotations

import base64
import json
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

from agents import safe_load  # noqa: E402
from agents.policy import load_sb3_policy, sidecar_paths  # noqa: E402
from agents.safe_load import MODELS_DIR, UnsafeModelError, shipped_models, verify_shipped  # noqa: E402

DATA = Path(__file__).parents[1] / "data" / "shipped_model_actions.npz"
SOURCE = "ppo_surface"


class _WriteFile:
    """Unpickling this writes ``path`` (stands for any code an attacker would run)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self):
        return (Path.write_text, (Path(self.path), "pwned"))


def _copy_model(dest: Path, name: str = "model") -> Path:
    """A copy of a shipped model (zip + sidecar + statistics) under ``dest``, outside agents/models."""
    dest.mkdir(parents=True, exist_ok=True)
    for src, dst in zip(sidecar_paths(MODELS_DIR / f"{SOURCE}.zip"), sidecar_paths(dest / f"{name}.zip")):
        shutil.copyfile(src, dst)
    return dest / f"{name}.zip"


def _rewrite_zip(path: Path, member: str, data: bytes) -> None:
    with zipfile.ZipFile(path) as z:
        members = {n: z.read(n) for n in z.namelist()}
    members[member] = data
    tmp = path.with_suffix(".tmp")
    with zipfile.ZipFile(tmp, "w") as z:
        for n, b in members.items():
            z.writestr(n, b)
    tmp.replace(path)


def _craft_data(path: Path, key: str, marker: Path, keep_description: bool = False) -> None:
    """Put a ``:serialized:`` payload writing ``marker`` under ``key`` of the zip's data (with
    ``keep_description``, beside the entry's original plain-text description)."""
    with zipfile.ZipFile(path) as z:
        data = json.loads(z.read("data"))
    described = data.get(key, {}) if keep_description else {":type:": "<class 'builtins.object'>"}
    data[key] = {**described, ":serialized:": base64.b64encode(pickle.dumps(_WriteFile(marker))).decode()}
    _rewrite_zip(path, "data", json.dumps(data).encode())


# --------------------------------------------------------------------------- shipped models
@pytest.mark.slow
def test_shipped_models_act_as_before_the_conversion():
    """Actions and network means on 32 fixed feature vectors equal those recorded with the old
    pickle-based loader (tests/data/shipped_model_actions.npz, recorded before the conversion)."""
    import torch
    ref = np.load(DATA)
    # the four models shipped with pickled statistics before the conversion (later models never had them)
    names = ["ppo_blade_wind_mix", "ppo_full_wind_mix", "ppo_surface", "ppo_surface_wind_mix"]
    assert set(names) <= set(shipped_models())
    for name in names:
        pol = load_sb3_policy("ppo", MODELS_DIR / f"{name}.zip")
        x = np.stack([pol.normalize(f) for f in ref["features"]])
        actions, _ = pol.model.predict(x, deterministic=True)
        with torch.no_grad():
            means = pol.model.policy.get_distribution(torch.as_tensor(x)).distribution.mean.numpy()
        # equal to float32 rounding: the reference was recorded on another CPU (AMD EPYC), whose
        # matrix kernels round differently in the last bits (2.4e-7 seen on an Intel Xeon); a lost or
        # wrong normalisation statistic moves these O(1) outputs by orders of magnitude more
        np.testing.assert_allclose(actions, ref[f"{name}/actions"], rtol=0, atol=1e-5, err_msg=name)
        np.testing.assert_allclose(means, ref[f"{name}/means"], rtol=0, atol=1e-5, err_msg=name)


def test_shipped_models_have_no_pickles_and_match_their_manifest():
    assert not list(MODELS_DIR.glob("*.pkl"))
    manifest = json.loads((MODELS_DIR / "MANIFEST.json").read_text())["files"]
    for name in shipped_models():
        for f in sidecar_paths(MODELS_DIR / f"{name}.zip"):
            assert f.name in manifest, f
        verify_shipped(MODELS_DIR / f"{name}.zip")
    import tomllib
    pyproject = tomllib.loads((Path(__file__).parents[2] / "pyproject.toml").read_text())
    patterns = pyproject["tool"]["setuptools"]["package-data"]["agents"]
    assert "models/*.json" in patterns and not any("pkl" in p for p in patterns)


def test_a_tampered_shipped_model_is_refused(tmp_path, monkeypatch):
    shipped = tmp_path / "models"
    zip_path = _copy_model(shipped, SOURCE)
    safe_load.write_manifest(shipped)
    monkeypatch.setattr(safe_load, "MODELS_DIR", shipped)
    load_sb3_policy("ppo", zip_path)                              # intact: loads
    for f in sidecar_paths(zip_path):
        original = f.read_bytes()
        f.write_bytes(original[:-1] + bytes([original[-1] ^ 1]))  # one bit changed
        for load in (lambda: load_sb3_policy("ppo", zip_path), lambda: verify_shipped(zip_path)):
            with pytest.raises(ValueError, match="SHA-256") as exc:
                load()
            msg = str(exc.value)
            assert str(f) in msg and "\n" not in msg
        f.write_bytes(original)
    (shipped / "extra.zip").write_bytes(zip_path.read_bytes())    # a model nobody shipped
    with pytest.raises(ValueError, match="not listed"):
        verify_shipped(shipped / "extra.zip")


# --------------------------------------------------------------------------- crafted files
def test_a_crafted_serialized_entry_is_refused_and_its_payload_never_runs(tmp_path):
    marker = tmp_path / "pwned.txt"
    path = _copy_model(tmp_path / "m")
    _craft_data(path, "evil_entry", marker)
    with pytest.raises(UnsafeModelError) as exc:
        load_sb3_policy("ppo", path)
    msg = str(exc.value)
    assert "evil_entry" in msg and str(path) in msg and "--trust-model" in msg and "\n" not in msg
    assert not marker.exists()
    from wt_inspect.evaluation import registry
    with pytest.raises(ValueError, match="evil_entry"):
        registry.check_controller(f"ppo:{path}")
    assert not marker.exists()
    # the same file with the user's explicit consent: SB3's own loader runs the payload
    with pytest.warns(UserWarning, match="trust-model"):
        load_sb3_policy("ppo", path, trust_model=True)
    assert marker.read_text() == "pwned"


def test_a_payload_in_an_entry_we_rebuild_is_never_unpickled(tmp_path):
    """A known entry (the learning rate) carrying a payload is replaced by the sidecar's value;
    if its description disagrees with the sidecar, the file is refused - unpickled either way never."""
    marker = tmp_path / "pwned.txt"
    path = _copy_model(tmp_path / "m")
    _craft_data(path, "learning_rate", marker, keep_description=True)
    pol = load_sb3_policy("ppo", path)
    assert not marker.exists()
    assert repr(pol.model.learning_rate) == "LinearSchedule(start=0.0003, end=0.0001, end_fraction=1.0)"
    _craft_data(path, "learning_rate", marker)
    with pytest.raises(ValueError, match="learning_rate.*does not match its sidecar"):
        load_sb3_policy("ppo", path)
    assert not marker.exists()


def test_a_crafted_weights_file_is_refused(tmp_path):
    import io

    import torch
    marker = tmp_path / "pwned.txt"
    path = _copy_model(tmp_path / "m")
    buf = io.BytesIO()
    torch.save({"w": _WriteFile(marker)}, buf)
    _rewrite_zip(path, "policy.pth", buf.getvalue())
    with pytest.raises(UnsafeModelError, match="policy.pth") as exc:
        load_sb3_policy("ppo", path)
    assert "\n" not in str(exc.value)
    assert not marker.exists()


def test_a_sidecar_that_does_not_describe_its_model_is_refused(tmp_path):
    path = _copy_model(tmp_path / "m")
    json_path = sidecar_paths(path)[1]
    doc = json.loads(json_path.read_text())
    doc["recipe"]["policy_kwargs"]["activation_fn"] = "relu"
    json_path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="policy_kwargs.*activation_fn"):
        load_sb3_policy("ppo", path)
    del doc["recipe"]
    json_path.write_text(json.dumps(doc))
    with pytest.raises(UnsafeModelError, match="no recipe"):
        load_sb3_policy("ppo", path)


def test_cli_refuses_a_crafted_model_in_one_line_and_writes_nothing(tmp_path, capsys):
    from agents.train_cli import main as train_main
    from wt_inspect.evaluation.cli import main as evaluate_main
    marker = tmp_path / "pwned.txt"
    path = _copy_model(tmp_path / "m")
    _craft_data(path, "evil_entry", marker)
    out = tmp_path / "eval"
    assert evaluate_main(["--scenario", "surface", "--controllers", f"ppo:{path}", "--winds", "0",
                          "--max-time", "0.1", "--out", str(out), "--no-progress", "--no-figures"]) == 2
    err = capsys.readouterr().err.strip()
    assert "evil_entry" in err and len(err.splitlines()) == 1
    assert not out.exists() and not marker.exists()
    out = tmp_path / "train"
    assert train_main(["--algo", "ppo", "--timesteps", "10", "--out", str(out), "--resume", str(path),
                       "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "evil_entry" in err and len(err.splitlines()) == 1
    assert not out.exists() and not marker.exists()


# --------------------------------------------------------------------------- normalisation statistics
def test_vecnormalize_statistics_round_trip_as_json(tmp_path):
    from gymnasium import spaces
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    class Box3:
        observation_space = spaces.Box(-1, 1, (3,), np.float32)
        action_space = spaces.Box(-1, 1, (1,), np.float32)

    def venv():
        import gymnasium as gym

        class E(gym.Env):
            observation_space, action_space = Box3.observation_space, Box3.action_space

            def reset(self, *, seed=None, options=None):
                return np.zeros(3, np.float32), {}

            def step(self, a):
                return np.zeros(3, np.float32), 0.0, False, False, {}
        return DummyVecEnv([E])

    vn = VecNormalize(venv(), clip_obs=7.0, gamma=0.95)
    vn.obs_rms.mean, vn.obs_rms.var, vn.obs_rms.count = np.array([0.1, -2.0, 1e-9]), np.array([1.5, 0.2, 3.0]), 1234.5
    vn.ret_rms.mean, vn.ret_rms.var, vn.ret_rms.count = 0.3, 4.5, 99.0
    p = safe_load.save_vecnormalize(vn, tmp_path / "m.vecnormalize.json")
    back = safe_load.load_vecnormalize(p, venv())
    np.testing.assert_array_equal(back.obs_rms.mean, vn.obs_rms.mean)
    np.testing.assert_array_equal(back.obs_rms.var, vn.obs_rms.var)
    assert back.obs_rms.count == 1234.5 and back.ret_rms.var == 4.5 and back.ret_rms.count == 99.0
    assert back.clip_obs == 7.0 and back.gamma == 0.95 and back.training
    doc = json.loads(p.read_text())
    doc["obs_rms"]["var"] = [1.0, -1.0, 1.0]
    p.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="obs_rms"):
        safe_load.load_vecnormalize(p, venv())
    doc["obs_rms"]["var"] = [1.0, 1.0]
    p.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="obs_rms.*shape"):
        safe_load.load_vecnormalize(p, venv())


def test_resume_refuses_an_old_pickled_statistics_file_without_trust(tmp_path):
    from agents.training import train
    path = _copy_model(tmp_path / "m")
    norm = sidecar_paths(path)[2]
    legacy = Path(str(path.with_suffix("")) + ".vecnormalize.pkl")
    norm.rename(legacy)
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=r"vecnormalize\.pkl.*--trust-model"):
        train("ppo", "surface", 10, 1, out, resume=path, progress_bar=False)
    assert not out.exists()
    legacy.unlink()
    with pytest.raises(ValueError, match="needs the normalisation statistics"):
        train("ppo", "surface", 10, 1, out, resume=path, progress_bar=False)


# --------------------------------------------------------------------------- issue 33: malformed files
def test_a_model_zip_whose_data_is_empty_is_one_error_naming_the_entry(tmp_path, capsys):
    from agents.train_cli import main as train_main
    path = _copy_model(tmp_path / "m")
    _rewrite_zip(path, "data", b"{}")
    for trust in (False, True):   # SB3's own loader would raise a bare KeyError either way
        with pytest.raises(ValueError, match=r"model\.zip.*no 'policy_class' entry"):
            load_sb3_policy("ppo", path, trust_model=trust)
    out = tmp_path / "train"
    assert train_main(["--algo", "ppo", "--timesteps", "10", "--out", str(out), "--resume", str(path),
                       "--no-progress", "--trust-model"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("wt-inspect train: error: model file") and "'policy_class'" in err[-1]
    assert not any("Traceback" in line for line in err)
    assert not out.exists()
    from wt_inspect.evaluation.cli import main as evaluate_main
    out = tmp_path / "eval"
    for trust in ([], ["--trust-model"]):   # refused before any run starts, with or without trust
        assert evaluate_main(["--scenario", "surface", "--controllers", f"ppo:{path}", "--winds", "0", "--max-time",
                              "0.1", "--out", str(out), "--no-progress", "--no-figures", *trust]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "'policy_class'" in err
        assert not out.exists()


def test_a_trusted_legacy_pickle_that_is_not_vecnormalize_is_refused_and_nothing_written(tmp_path):
    from agents.training import train
    path = _copy_model(tmp_path / "m")
    norm = sidecar_paths(path)[2]
    norm.unlink()
    legacy = Path(str(path.with_suffix("")) + ".vecnormalize.pkl")
    legacy.write_bytes(pickle.dumps({"obs_rms": [1, 2, 3]}))
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=r"vecnormalize\.pkl.*builtins\.dict, not VecNormalize"):
        train("ppo", "surface", 10, 1, out, resume=path, progress_bar=False, trust_model=True)
    assert not out.exists()   # refused before recipe.json (or anything) is written


def test_a_refused_resume_leaves_no_recipe_behind(tmp_path):
    from agents.training import train
    path = _copy_model(tmp_path / "m")
    norm = sidecar_paths(path)[2]
    doc = json.loads(norm.read_text())
    doc["obs_rms"]["var"] = [-1.0] * len(doc["obs_rms"]["var"])   # refused only once the statistics are read
    norm.write_text(json.dumps(doc))
    out = tmp_path / "out"
    with pytest.raises(ValueError, match="obs_rms"):
        train("ppo", "surface", 10, 1, out, resume=path, progress_bar=False)
    assert not out.exists()

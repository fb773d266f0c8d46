"""Bad input everywhere, table-driven: every row is one mistake a user can make; each gives exit status 2 (or
the API's error type) and one message that names the problem, and nothing saved before is changed."""

import hashlib

import pytest

from seqdex_drake.cli.main import main


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A tiny trained reach run (``seqdex train --test``) to point the bad commands at."""
    directory = tmp_path_factory.mktemp("runs") / "reach"
    assert main(["train", "--task", "reach", "--test", "--num-envs", "1", "--run-dir", str(directory)]) == 0
    return directory


def _digest(directory) -> dict:
    return {path.name: hashlib.sha256(path.read_bytes()).hexdigest() for path in sorted(directory.glob("*.pt"))}


# (argv with {run} / {tmp} placeholders, expected exit code, text the message must contain)
ROWS = [
    (["train", "--task", "nope", "--test"], 2, "invalid choice"),
    (["pipeline", "--chain", "nope", "--test"], 2, "invalid choice"),
    (["pipeline", "--chain", "handover", "--method", "nope", "--test"], 2, "invalid choice"),
    (["train", "--task", "lower", "--test", "--initial-states", "{tmp}/missing.npz", "--run-dir", "{tmp}/l"], 2,
     "seqdex collect --task reach"),
    (["train", "--task", "reach", "--test", "--run-dir", "{run}"], 2, "already holds a run"),
    (["train", "--task", "reach", "--test", "--resume", "--run-dir", "{tmp}/none"], 2, "no checkpoint"),
    (["collect", "--task", "reach", "--checkpoint", "{tmp}/missing.pt", "--test", "--out", "{tmp}/b.npz"], 2,
     "does not exist"),
    (["collect", "--task", "reach", "--checkpoint", "{tmp}/corrupt.pt", "--test", "--out", "{tmp}/b.npz"], 2,
     "corrupt.pt"),
    (["collect", "--task", "grasp", "--checkpoint", "{run}/last.pt", "--test", "--out", "{tmp}/b.npz"], 2,
     "another task"),
    (["collect", "--task", "lower", "--checkpoint", "{run}/last.pt", "--test"], 2, "last sub-task"),
    (["feasibility", "--run-dir", "{run}", "--task", "lower"], 2, "holds no pipeline run"),
    (["finetune", "--run-dir", "{tmp}/none"], 2, "holds no pipeline run"),
    (["evaluate", "--run-dir", "{tmp}/none", "--test"], 2, "does not exist"),
]


@pytest.mark.parametrize("argv, code, text", ROWS, ids=[" ".join(row[0][:2]) + f" #{i}" for i, row in
                                                         enumerate(ROWS)])
def test_cli_bad_input(run_dir, tmp_path, capsys, argv, code, text):
    (tmp_path / "corrupt.pt").write_bytes(b"this is not a checkpoint")
    before = _digest(run_dir)
    argv = [a.replace("{run}", str(run_dir)).replace("{tmp}", str(tmp_path)) for a in argv]
    try:
        result = main(argv)
    except SystemExit as exit_:  # argparse: usage and the valid choices on stderr.
        result = exit_.code
    assert result == code
    err = capsys.readouterr().err
    assert text in err and "Traceback" not in err
    assert _digest(run_dir) == before  # Nothing saved was touched.


def test_typed_configs_reject_unknown_keys():
    from seqdex_drake.rl.config import PPOConfig
    from seqdex_drake.scenario import LoadScenario, ScenarioError

    with pytest.raises(ScenarioError, match="bogus"):
        LoadScenario("handover/reach", scenario_text="{bogus: 1}")
    with pytest.raises(ValueError, match="bogus"):
        PPOConfig.from_dict({"bogus": 1})


def test_unknown_task_lists_the_valid_ones():
    from seqdex_drake.envs.subtask_env import make_env

    with pytest.raises(ValueError, match="valid tasks: search, retrieve, orient"):
        make_env("nope")

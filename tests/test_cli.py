import json

import pytest

from helpers import mikt


def test_envs_json_parses():
    data = json.loads(mikt("envs", "--json").stdout)
    dims = {d["name"]: (d["obs_dim"], d["act_dim"]) for d in data}
    assert dims["centipede-six"] == (139, 16) and dims["ant"] == (111, 8) and len(dims) == 10


def test_envs_show_and_render(tmp_path):
    assert "actuators (10)" in mikt("envs", "show", "centipede-four").stdout
    out = tmp_path / "f.png"
    mikt("envs", "render", "centipede-four", "--out", out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_known_errors_are_one_line_and_exit_1(tmp_path, monkeypatch):
    r = mikt("envs", "show", "centipede-five", code=1)
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert lines[0].startswith("Error: unknown environment 'centipede-five'; known: ant")
    assert "Traceback" not in r.output
    (tmp_path / "broken.toml").write_text('name = "broken"\nfamily = "centipede"\nlegs = 4\nact_dim = 10\n')
    monkeypatch.setenv("MIKT_ENVSPECS", str(tmp_path))
    r = mikt("envs", code=1)
    assert "broken.toml: field 'obs_dim'" in r.output


def test_usage_errors_exit_2():
    mikt("envs", "--bogus", code=2)
    mikt("transfer", "--steps", "many", code=2)


def test_bad_teacher_reference(registry):
    assert "unknown teacher 'ghost'" in mikt("eval", "ghost", code=1).output
    assert "unknown run 'run9'" in mikt("inspect", "run9", code=1).output


@pytest.mark.slow
def test_end_to_end_teacher_transfer_inspect_eval(registry, tmp_path):
    r = mikt("teacher", "train", "centipede-four", "--steps", 2048)
    assert r.stdout.strip() == "centipede-four@v1"
    listed = json.loads(mikt("teacher", "list", "--json").stdout)
    assert listed[0]["card"]["obs_dim"] == 97 and listed[0]["card"]["steps"] == 2048
    assert "centipede-four" in mikt("teacher", "show", "centipede-four").stdout
    r = mikt("eval", "centipede-four", "--episodes", 2, "--json")
    assert json.loads(r.stdout)["episodes"] == 2
    teacher_file = registry / "teachers" / "centipede-four" / "v1.safetensors"
    before = teacher_file.read_bytes()

    r = mikt("transfer", "--from", "centipede-four", "--to", "centipede-six", "--steps", 4096,
             "--coupling-schedule", "constant", "--eval-episodes", 2, "--json")
    result = json.loads(r.stdout)
    assert result["run"] == "run2"
    assert set(result["final_mixing"]) == {"p_pi_0", "p_pi_1", "p_vf_0", "p_vf_1"}
    assert "eval_with_teacher" in result and "eval_without_teacher" in result
    assert teacher_file.read_bytes() == before  # the teacher stayed frozen

    r = mikt("inspect", "run2", "--coupling", "--plot", tmp_path / "p.png")
    assert "layer 0 student" in r.stdout and "layer 1 centipede-four" in r.stdout and (tmp_path / "p.png").exists()
    assert "mean return" in mikt("inspect", "run2", "--curve").stdout
    everything = json.loads(mikt("inspect", "run2", "--json").stdout)
    assert everything["card"]["teachers"][0]["obs_dim"] == 97  # the encoder's width, from the teacher's card
    assert len(everything["metrics"]) == 2 and "loss_mi" in everything["metrics"][0]
    assert "student on centipede-six" in mikt("eval", "run2", "--episodes", 1).stdout
    assert "student + teacher" in mikt("eval", "run2", "--with-teacher", "--episodes", 1).stdout
    video = tmp_path / "v.mp4"
    mikt("eval", "run2", "--episodes", 1, "--video", video, "--video-frames", 5)
    assert video.stat().st_size > 0 and video.with_suffix(".png").exists()

    runs = json.loads(mikt("runs", "--json").stdout)
    assert [r["status"] for r in runs] == ["completed", "completed"]

    # explicit options that contradict the card fail before any run exists
    r = mikt("transfer", "--from", "centipede-four", "--to", "ant", "--encoder-width", 111, code=1)
    assert "state dim 97 (from its card), encoder width 111 requested" in r.output
    assert "Hint: --encoder-width must equal each teacher's state dim" in r.output
    assert len(json.loads(mikt("runs", "--json").stdout)) == 2


@pytest.mark.parametrize(
    "args,card,metrics_present,metrics_absent",
    [
        (("--method", "vpg"), {"method": "vpg", "kl_coef": 0.0, "mikt": None}, set(), {"loss_mi", "loss_kl"}),
        (("--from", "tiny", "--method", "mlpp"), {"method": "mlpp", "kl_coef": 0.0, "mikt": None}, set(),
         {"loss_mi", "loss_kl"}),
        (("--from", "tiny", "--no-mi"), {"method": "mikt", "kl_coef": 0.05, "mi": False}, {"loss_kl"},
         {"loss_mi"}),
        (("--from", "tiny", "--no-rl-encoder-grad", "--kl-coef", "0"),
         {"method": "mikt", "kl_coef": 0.0, "rl_encoder_grad": False}, {"loss_mi"}, {"loss_kl"}),
        (("--from", "tiny", "--lateral", "projection"), {"method": "mikt", "lateral": "projection"},
         {"loss_mi", "loss_kl"}, set()),
        (("--from", "tiny@v1", "--from", "tiny@v2"), {"method": "mikt", "teachers": 2, "mixing": "per-teacher"},
         {"p_pi_0", "w_pi_0_t0", "w_vf_1_t1", "loss_mi"}, {"w_pi_0_shared"}),
        (("--from", "tiny@v1", "--from", "tiny@v2", "--mixing", "shared", "--lateral", "projection"),
         {"method": "mikt", "teachers": 2, "mixing": "shared", "lateral": "projection"},
         {"p_pi_0", "w_pi_0_shared", "w_vf_1_shared", "loss_mi"}, {"w_pi_0_t0"}),
        (("--from", "tiny", "--coupling-ramp", "student-weight", "--mi-log-std-min", "-11"),
         {"method": "mikt", "coupling_ramp": "student-weight", "mi_log_std_min": -11.0}, {"loss_mi"}, set()),
    ],
    ids=["vpg", "mlpp", "no-mi", "no-rl-grad-no-kl", "projection", "two-teachers", "two-teachers-shared",
         "student-weight-ramp"],
)
def test_methods_and_ablations_are_recorded_and_change_what_is_trained(
        registry, args, card, metrics_present, metrics_absent, teacher):
    if "tiny@v2" in args:  # a second, different teacher (the same one twice is refused)
        mikt("teacher", "train", "hopper", "--steps", 2048, "--name", "tiny", "--seed", 1)
    r = mikt("transfer", *args, "--to", "centipede-four", "--steps", 2048, "--eval-episodes", 1, "--json")
    result = json.loads(r.stdout)
    assert result["eval_without_teacher"]["episodes"] == 1
    everything = json.loads(mikt("inspect", result["run"], "--json").stdout)
    config, metrics = everything["card"]["config"], everything["metrics"][0]
    recorded = {"method": everything["card"]["method"], "kl_coef": config["ppo"]["kl_coef"],
                "mikt": config.get("options"), "teachers": len(everything["card"]["teachers"]),
                **(config.get("options") or {})}
    assert {k: recorded[k] for k in card} == card
    assert metrics_present <= set(metrics) and not metrics_absent & set(metrics)
    assert config["ppo"]["clip_actions_for_env"] is False


@pytest.mark.slow
@pytest.mark.parametrize("mixing", ["per-teacher", "shared"])
def test_inspect_coupling_shows_and_plots_every_teachers_weight(registry, tmp_path, mixing):
    mikt("teacher", "train", "hopper", "--steps", 2048, "--name", "hop")
    mikt("teacher", "train", "centipede-four", "--steps", 2048, "--name", "four")
    mikt("transfer", "--from", "hop", "--from", "four", "--to", "centipede-four", "--steps", 4096,
         "--mixing", mixing, "--coupling-schedule", "constant", "--eval-episodes", 1)
    png = tmp_path / "w.png"
    out = mikt("inspect", "run3", "--coupling", "--plot", png).stdout
    assert "policy: weight of each source per layer" in out and "value: weight" in out
    teachers = ["hop", "four"] if mixing == "per-teacher" else ["hop + four (shared)"]
    for layer in (0, 1):
        assert f"layer {layer} student" in out
        assert all(f"layer {layer} {name}" in out for name in teachers)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_ctrl_c_keeps_the_last_checkpoint_and_resumes(registry, ctrl_c_at_second_update):
    r = mikt("teacher", "train", "hopper", "--steps", 6144, code=1)
    assert "interrupted; run1 keeps its last complete checkpoint" in r.output
    card = json.loads(mikt("runs", "--json").stdout)[0]
    assert card["status"] == "interrupted" and card["steps_done"] == 2048
    assert not list(registry.glob("teachers/**/*.safetensors"))  # no half-trained teacher was published
    assert "mean return" in mikt("inspect", "run1", "--curve").stdout

    r = mikt("teacher", "train", "--resume", "run1")
    assert r.stdout.strip() == "hopper@v1"
    card = json.loads(mikt("runs", "--json").stdout)[0]
    assert card["status"] == "completed" and card["steps_done"] == 6144
    metrics = json.loads(mikt("inspect", "run1", "--json").stdout)["metrics"]
    assert [m["iteration"] for m in metrics] == [1, 2, 3]


@pytest.mark.slow
def test_the_card_records_which_code_trained_which_steps(registry, ctrl_c_at_second_update, monkeypatch):
    from miktcli.registry.cards import code_version
    from miktcli.registry.runs import open_run
    from miktcli.workflows import session

    mikt("teacher", "train", "hopper", "--steps", 8192, code=1)  # interrupted after 2,048 steps
    history = json.loads(mikt("inspect", "run1", "--json").stdout)["card"]["code_history"]
    assert [(h["from_step"], h["code_version"]) for h in history] == [(0, code_version())]

    ctrl_c_at_second_update()
    monkeypatch.setattr(session, "code_version", lambda: "abc1234")  # as if the checkout moved on
    mikt("teacher", "train", "--resume", "run1")
    card = json.loads(mikt("inspect", "run1", "--json").stdout)["card"]
    assert [(h["from_step"], h["code_version"]) for h in card["code_history"]] == [(0, code_version()),
                                                                                   (2048, "abc1234")]
    assert card["code_version"] == code_version()  # the code that created the run
    # Resuming under the same code (a study's next chunk) adds no segment.
    history = open_run(registry, "run1").card.code_history
    assert session.continued_code_history(history, 8192) == history
    teacher = json.loads(mikt("teacher", "show", "hopper", "--json").stdout)
    assert teacher["code_history"] == card["code_history"]
    shown = mikt("inspect", "run1").stdout
    assert f"{code_version()} from step 0; abc1234 from step 2,048" in shown


def test_cards_from_before_the_code_history_say_it_was_not_recorded(registry):
    from miktcli.registry.cards import describe_code_history
    from miktcli.registry.runs import open_run

    mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 2048, "--eval-episodes", 1)
    path = registry / "runs" / "run1" / "run.json"
    old = json.loads(path.read_text())
    old.pop("code_history")
    path.write_text(json.dumps(old))
    card = open_run(registry, "run1").card
    assert card.code_history == []
    assert f"not recorded (run created with {card.code_version})" in mikt("inspect", "run1").stdout
    assert describe_code_history([], "f00d123", trained=False) == "not trained yet"


def test_a_segment_that_trained_nothing_is_replaced_not_followed(monkeypatch):
    from miktcli.registry.cards import CodeSegment, now
    from miktcli.workflows import session

    def segment(step, commit):
        return CodeSegment(from_step=step, code_version=commit, packages={}, started=now())

    monkeypatch.setattr(session, "package_versions", lambda: {})
    monkeypatch.setattr(session, "code_version", lambda: "c")
    history = [segment(0, "a"), segment(4096, "b")]  # b stopped before its first checkpoint
    assert [(s.from_step, s.code_version) for s in session.continued_code_history(history, 4096)] == [
        (0, "a"), (4096, "c")]
    assert [(s.from_step, s.code_version) for s in session.continued_code_history(history, 6144)] == [
        (0, "a"), (4096, "b"), (6144, "c")]


def test_tampered_teacher_is_refused_by_transfer(registry):
    mikt("teacher", "train", "hopper", "--steps", 2048)
    path = registry / "teachers" / "hopper" / "v1.safetensors"
    data = bytearray(path.read_bytes())
    data[-5] ^= 0xFF  # flip bits inside the last tensor
    path.write_bytes(bytes(data))
    r = mikt("transfer", "--from", "hopper", "--to", "centipede-four", "--steps", 2048, code=1)
    assert "sha256" in r.output and "Traceback" not in r.output


def test_checkpoints_carry_the_run_card(registry):
    from miktcli.registry.runs import open_run

    mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 2048, "--eval-episodes", 1)
    ckpt, tensors = open_run(registry, "run1").load_checkpoint()
    assert ckpt.run.run_id == "run1" and ckpt.run.config.ppo.n_steps == 2048
    assert "agent.obs_normalizer.mean" in tensors and "optim.exp_avg" in tensors


def test_steps_round_up_to_whole_rollouts_and_say_so(registry):
    r = mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 3000, "--eval-episodes", 1)
    assert "--steps 3,000 is not a whole number of rollouts: training 4,096 steps" in r.output
    card = json.loads(mikt("runs", "--json").stdout)[0]
    assert card["total_steps"] == 4096 and card["steps_done"] == 4096


def test_shell_completion_is_on(monkeypatch):
    monkeypatch.setenv("SHELL", "/bin/bash")
    assert "--install-completion" in mikt("--help").stdout
    assert "_mikt_completion" in mikt("--show-completion", "bash").stdout


def test_eval_reports_how_far_and_how_fast_the_body_moved(registry, teacher):
    out = json.loads(mikt("eval", "tiny", "--episodes", 2, "--json").stdout)
    assert {"distance_mean", "distance_std", "speed_mean"} <= out.keys()
    assert "forward" in mikt("eval", "tiny", "--episodes", 1).stdout


def test_the_forward_position_is_what_each_family_rewards():
    from miktcli.envs import make_env
    from miktcli.envs.factory import forward_position

    for name, own in (("centipede-four", lambda e: e.unwrapped.front_x()),  # the forward reward's x
                      ("hopper", lambda e: float(e.unwrapped.data.qpos[0])),  # gymnasium's x_position
                      ("ant", lambda e: float(e.unwrapped.data.qpos[0]))):
        env = make_env(name)
        env.reset(seed=0)
        env.step(env.action_space.sample())
        assert forward_position(env) == own(env)
        env.close()

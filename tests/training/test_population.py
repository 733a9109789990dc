"""Populations (`training/population.py`): run k of a population trains as the same config alone (bit
for bit on the CPU), resumes bit for bit, stops alone when it fails, and the stacked learner (one
batched update of every run) computes each run's own update."""

from __future__ import annotations

import copy
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time

import pytest
import torch

from aquarium_warp.training import Trainer, make_config
from aquarium_warp.training.population import Population, StackedPPO, resume_population, run_configs

# A population small enough for the CPU: 4 worlds of 4 prey per run, 8 steps per rollout.
CHANGES = {
    "train": {"num_worlds": 4, "iterations": 3, "quiet": True, "export": [], "metrics_every": 0},
    "runner": {"num_steps_per_env": 8, "save_interval": 2},
}


def base_config(**train) -> dict:
    config = make_config("tiny", copy.deepcopy(CHANGES))
    config["train"].update(train)
    return config


def conditions() -> list[dict]:
    """Three runs that differ in all a population lets differ: seed, reward scale, a per-world
    parameter (run 1's prey see farther) and the budget (run 2 trains 2 iterations, the others 3); each
    normalises its observations."""
    configs = run_configs(base_config(), 3)
    for config in configs:  # each run's own observation normaliser
        config["runner"]["actor"]["obs_normalization"] = config["runner"]["critic"]["obs_normalization"] = True
    configs[1]["env"]["prey"] = {"view_distance": 150.0}
    configs[1]["train"]["reward_scale"] = 0.02
    configs[2]["train"]["iterations"] = 2
    return configs


def parameters(alg) -> dict[str, torch.Tensor]:
    return {f"{part}.{name}": p.detach().clone() for part in ("actor", "critic")
            for name, p in getattr(alg, part).named_parameters()}  # fmt: skip


def optimizer_state(alg) -> list[torch.Tensor]:
    state = alg.optimizer.state_dict()["state"]
    return [v for i in sorted(state) for v in state[i].values() if isinstance(v, torch.Tensor)]


def assert_same(a: dict, b: dict, where: str) -> None:
    assert a.keys() == b.keys()
    for name in a:
        assert torch.equal(a[name], b[name]), (
            f"{where}: {name} differs (largest {float((a[name] - b[name]).abs().max())})"
        )


def alone(config: dict, log_dir=None) -> Trainer:
    trainer = Trainer(config, log_dir=log_dir)
    trainer.train()
    return trainer


@pytest.mark.slow
def test_each_run_trains_bit_for_bit_as_it_would_alone(tmp_path):
    configs = conditions()
    population = Population(configs, log_dir=str(tmp_path / "pop"), stacked=False)
    population.train()
    assert population.iteration == 3 and population.active == [False] * 3 and not population.stopped
    for k, config in enumerate(configs):
        trainer = alone(config, log_dir=str(tmp_path / f"alone-{k}"))
        run = population.runs[k]
        assert_same(parameters(trainer.runner.alg), parameters(run), f"run {k}")
        for x, y in zip(optimizer_state(trainer.runner.alg), optimizer_state(run)):
            assert torch.equal(x, y), f"run {k}: optimizer state differs"
        # its files are those of the run alone: the same checkpoints, and the same parameters in them
        own = sorted(n for n in os.listdir(tmp_path / "pop" / f"run-{k}") if n.startswith("model_"))
        assert own == sorted(n for n in os.listdir(tmp_path / f"alone-{k}") if n.startswith("model_"))
        last = torch.load(tmp_path / "pop" / f"run-{k}" / own[-1], weights_only=False)
        reference = torch.load(tmp_path / f"alone-{k}" / own[-1], weights_only=False)
        assert last["iter"] == reference["iter"] == config["train"]["iterations"]
        assert_same(last["actor_state_dict"], reference["actor_state_dict"], f"run {k}'s checkpoint")
        assert last["infos"]["aquarium"]["config"] == reference["infos"]["aquarium"]["config"]
        ours = last["infos"]["aquarium"]["vec_env"]["env"]
        theirs = reference["infos"]["aquarium"]["vec_env"]["env"]
        assert ours["seed"] == theirs["seed"] and ours["config"] == theirs["config"]
        assert_same(ours["tensors"], theirs["tensors"], f"run {k}'s worlds")
        trainer.close()
    population.close()


@pytest.mark.slow
def test_a_population_resumes_bit_for_bit_and_its_runs_resume_alone(tmp_path):
    configs = run_configs(base_config(iterations=4), 2)
    whole = Population(configs, stacked=False)
    whole.train()
    first = Population(configs, log_dir=str(tmp_path / "pop"), stacked=False)
    for config in first.configs:
        config["train"]["iterations"] = 2  # stop after 2, then resume with the budget of 4
    first.totals = [2, 2]
    first.train()
    first.close()
    resumed = resume_population(str(tmp_path / "pop"), {"train": {"iterations": 4}})
    assert resumed.iteration == 2 and resumed.active == [True, True]
    resumed.train()
    for k in range(2):
        assert_same(parameters(whole.runs[k]), parameters(resumed.runs[k]), f"resumed run {k}")
    # a run's checkpoint is a run's own: Trainer resumes it alone, bit for bit
    trainer = Trainer.resume(str(tmp_path / "pop" / "run-1" / "model_1.pt"), log_dir=str(tmp_path / "r1"),
                             changes={"train": {"iterations": 4}})  # fmt: skip
    trainer.train()
    assert_same(parameters(whole.runs[1]), parameters(trainer.runner.alg), "run 1 resumed alone")
    trainer.close()
    resumed.close()
    whole.close()


@pytest.mark.slow
@pytest.mark.parametrize("stacked", [False, True], ids=["per-run", "stacked"])
def test_a_failing_run_stops_alone(tmp_path, stacked):
    """Run 1's parameters poisoned with NaN after its first checkpoint: it stops, is reported, goes back
    to that checkpoint's parameters; runs 0 and 2 train exactly as in an unpoisoned population."""
    configs = run_configs(base_config(iterations=4), 3)
    clean = Population(configs, stacked=stacked)
    clean.train()
    poisoned = Population(configs, log_dir=str(tmp_path / "pop"), stacked=stacked)
    save = poisoned.save

    def poison_after_first_save(runs):
        save(runs)
        if 1 in runs and poisoned.iteration == 1:
            with torch.no_grad():
                next(poisoned.runs[1].actor.parameters()).fill_(float("nan"))

    poisoned.save = poison_after_first_save
    poisoned.train()
    assert poisoned.active == [False] * 3 and list(poisoned.stopped) == [1]
    assert "non-finite" in poisoned.stopped[1] and "iteration 1" in poisoned.stopped[1]
    for k in (0, 2):
        assert_same(parameters(clean.runs[k]), parameters(poisoned.runs[k]), f"run {k} beside the failed one")
    first = torch.load(tmp_path / "pop" / "run-1" / "model_0.pt", weights_only=False)
    assert_same(first["actor_state_dict"], dict(poisoned.runs[1].actor.state_dict()),
                "the failed run's parameters")  # fmt: skip
    assert sorted(os.listdir(tmp_path / "pop" / "run-1")).count("model_3.pt") == 0
    with open(tmp_path / "pop" / "population.json") as f:
        assert "1" in json.load(f)["stopped"]
    clean.close()
    poisoned.close()


def rolled_out(configs: list[dict]) -> Population:
    """A per-run population (the CPU's reference) after one rollout and its returns."""
    from aquarium_warp.training.loop import TrainingLoop

    population = Population(configs, stacked=False)
    loop = TrainingLoop([(population.learner, population.vec_env)], 8, graphs=False)
    with torch.inference_mode():
        for _ in range(8):
            loop._rollout_step()
        population.learner.compute_returns(loop.obs[0])
    return population


def copy_rollouts(per_run: Population, stacked: Population) -> None:
    """The per-run learners' rollouts into the stacked learner's one storage (its device)."""
    big, n, dev = stacked.learner.storage, per_run.rows, stacked.device
    for k, alg in enumerate(per_run.runs):
        own = alg.storage
        for name in ("actions", "rewards", "dones", "values", "actions_log_prob", "returns"):
            getattr(big, name)[:, k * n : (k + 1) * n] = getattr(own, name).to(dev)
        big.observations["policy"][:, k * n : (k + 1) * n] = own.observations["policy"].to(dev)
    big.advantages = torch.cat([alg.storage.advantages for alg in per_run.runs], dim=1).to(dev)  # per run
    big.distribution_params = (torch.cat([a.storage.distribution_params[0] for a in per_run.runs], dim=1).to(dev),)
    big.step = big.num_transitions_per_env


@pytest.mark.parametrize("fused, normalised", [(False, False), (True, False), (False, True)],
                         ids=["torch", "fused", "torch-normalised"])  # fmt: skip
def test_the_stacked_update_is_each_runs_own(device, fused, normalised):
    """One update of a `StackedPPO` (on the test device; torch's autograd or the fused kernels, which
    the CPU runs under Triton's interpreter) over the rollouts of 3 runs, with the same permutations
    and parameters as each run's own `AquariumPPO` on the CPU, gives each run the losses and the
    parameters its own update gives (float32: to rounding)."""
    if fused:
        pytest.importorskip("triton")
        from aquarium_warp.training import fused_mlp

        if device == "cpu" and not fused_mlp.INTERPRETED:
            pytest.skip("the fused kernels need CUDA or Triton's interpreter")
    configs = run_configs(base_config(), 3)
    for config in configs:
        config["runner"]["actor"]["obs_normalization"] = config["runner"]["critic"]["obs_normalization"] = normalised
    per_run = rolled_out(configs)
    stacked = Population([dict(c, train={**c["train"], "device": device, "fused_mlp": fused}) for c in configs],
                         stacked=True)  # fmt: skip
    assert isinstance(stacked.learner, StackedPPO) and (stacked.learner.fused_loss is not None) == fused
    for k in range(3):  # the same networks to start from
        assert_same(parameters(per_run.runs[k]), {n: p.cpu() for n, p in parameters(stacked.runs[k]).items()},
                    f"run {k} at the start")  # fmt: skip
    copy_rollouts(per_run, stacked)
    indices, size = per_run.learner.mini_batch_indices()
    losses_per_run = per_run.learner.update_on_device(indices, size).view(3, 3)
    losses_stacked = stacked.learner.update_on_device(indices.to(stacked.device), size).view(3, 3).cpu()
    torch.testing.assert_close(losses_stacked, losses_per_run, rtol=1e-4, atol=1e-6)
    for k in range(3):
        a, b = parameters(per_run.runs[k]), parameters(stacked.runs[k])
        for name in a:
            torch.testing.assert_close(b[name].cpu(), a[name], rtol=1e-4, atol=1e-5, msg=f"run {k}: {name}")
    if normalised:  # then each run's normaliser learns from its own rollout
        per_run.learner.finish_update()
        stacked.learner.finish_update()
        for k in range(3):
            for part in ("actor", "critic"):
                a, b = (getattr(p.runs[k], part).obs_normalizer for p in (per_run, stacked))
                assert int(a.count) == int(b.count) > 0
                torch.testing.assert_close(b._mean.cpu(), a._mean, rtol=1e-5, atol=1e-6)
                torch.testing.assert_close(b._std.cpu(), a._std, rtol=1e-5, atol=1e-6)
    per_run.close()
    stacked.close()


@pytest.mark.parametrize("fused", [False, True], ids=["torch", "fused"])
def test_the_stacked_rollout_step_is_each_runs_own(device, fused):
    """One rollout step of the stacked learner (torch's forward or the fused kernel over each run's
    block of rows) stores what each run's own network computes for its rows: values and
    log-probabilities to rounding, and the same sampled actions from the same noise."""
    if fused:
        pytest.importorskip("triton")
        from aquarium_warp.training import fused_mlp

        if device == "cpu" and not fused_mlp.INTERPRETED:
            pytest.skip("the fused kernels need CUDA or Triton's interpreter")
    configs = [
        dict(c, train={**c["train"], "device": device, "fused_mlp": fused}) for c in run_configs(base_config(), 3)
    ]
    population = Population(configs, stacked=True)
    alg, v = population.learner, population.vec_env
    obs = v.get_observations()
    gen_state = torch.get_rng_state() if population.device.type == "cpu" else torch.cuda.get_rng_state()
    with torch.inference_mode():
        alg.act_into(obs, v.actions_buffer)
        rewards, dones, extras = v.outputs
        alg.process_env_step(obs, rewards, dones, extras)  # (torch's path stores the step here)
    st, n = alg.storage, population.rows
    for k, run in enumerate(population.runs):
        rows = obs["policy"][k * n : (k + 1) * n]
        with torch.inference_mode():
            values = run.critic(obs[k * n : (k + 1) * n])
            logits = run.actor.mlp(rows)
        torch.testing.assert_close(st.values[0, k * n : (k + 1) * n], values, rtol=1e-4, atol=1e-5)
        log_probs = torch.log_softmax(logits, dim=-1)
        taken = st.actions[0, k * n : (k + 1) * n].long()
        torch.testing.assert_close(st.actions_log_prob[0, k * n : (k + 1) * n], log_probs.gather(1, taken),
                                   rtol=1e-4, atol=1e-5)  # fmt: skip
    # the actions are argmax(p / Exp(1)) of the generator's next draw, as rsl-rl's sampler draws it
    if population.device.type == "cpu":
        torch.set_rng_state(gen_state)
    else:
        torch.cuda.set_rng_state(gen_state)
    noise = torch.empty(st.num_envs, 16, device=population.device).exponential_(1)
    expected = torch.argmax(st.distribution_params[0][0].exp() / noise, dim=-1)
    assert (expected == st.actions[0].squeeze(1).long()).float().mean() > 0.99
    population.close()


def test_stacked_advantages_are_normalised_per_run():
    configs = run_configs(base_config(), 2)
    population = Population(configs, stacked=True)
    st = population.learner.storage
    gen = torch.Generator().manual_seed(0)
    st.values.copy_(torch.randn(st.values.shape, generator=gen))
    st.rewards.copy_(torch.randn(st.rewards.shape, generator=gen))
    st.rewards[:, : population.rows] *= 10.0  # run 0's rewards on another scale than run 1's
    st.dones.zero_()
    with torch.inference_mode():
        population.learner.compute_returns(population.vec_env.get_observations())
    adv = st.advantages.view(st.num_transitions_per_env, 2, -1)
    for k in range(2):
        run = adv[:, k]
        assert abs(float(run.mean())) < 1e-5 and abs(float(run.std()) - 1.0) < 1e-4
    population.close()


@pytest.mark.parametrize(
    "change, message",
    [
        ({"train": {"team": "both"}}, "both teams learning"),
        ({"train": {"video_every": 2}}, "training videos"),
        ({"train": {"sharing": "individual"}}, "Individual Learning"),
        ({"train": {"critic": "team"}}, "centralised critic"),
        ({"runner": {"actor": {"class_name": "RNNModel"}, "critic": {"class_name": "RNNModel"}}}, "recurrent"),
        ({"train": {"randomize": {"prey_max_speed": "1:2"}}}, "domain randomisation"),
        ({"train": {"team": "predator", "opponent": "prey-a", "opponent_deterministic": False}}, "samples its actions"),
    ],
)
def test_what_a_population_does_not_train_is_refused_in_one_line(change, message):
    config = make_config("tiny", copy.deepcopy(CHANGES))
    from aquarium_warp.training.config import deep_update

    deep_update(config, change)
    with pytest.raises(ValueError, match=message) as error:
        Population(run_configs(config, 2))
    assert "\n" not in str(error.value) and "--runs 1" in str(error.value)


def test_runs_that_cannot_share_a_process_are_refused():
    configs = run_configs(base_config(), 2)
    configs[1]["env"]["prey_count"] = 8  # another slot count
    with pytest.raises(ValueError, match="differ in prey_count"):
        Population(configs)
    configs = run_configs(base_config(), 2)
    configs[1]["runner"]["algorithm"]["entropy_coef"] = 0.5
    with pytest.raises(ValueError, match=r"runs 0 and 1 differ in runner.algorithm"):
        Population(configs)
    configs = run_configs(base_config(), 2)
    configs[1]["train"]["seed"] = configs[0]["train"]["seed"]
    with pytest.raises(ValueError, match="runs 0 and 1 are the same run"):
        Population(configs)
    configs[1]["train"]["reward_scale"] = 0.02  # one seed under another condition is another run
    Population(configs).close()


@pytest.mark.slow
def test_train_runs_through_the_cli_writes_each_run_and_resumes(tmp_path):
    out = tmp_path / "pop"
    command = [
        sys.executable,
        "-m",
        "aquarium_warp",
        "train",
        "--preset",
        "tiny",
        "--runs",
        "2",
        "--num-worlds",
        "4",
        "--iterations",
        "2",
        "--log-dir",
        str(out),
        "--set",
        "runner.num_steps_per_env=8",
        "--quiet",
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "2 runs of prey" in done.stdout
    for k in range(2):
        files = os.listdir(out / f"run-{k}")
        assert {"config.json", "progress.csv", "model_1.pt", "exported"} <= set(files)
        with open(out / f"run-{k}" / "config.json") as f:
            assert json.load(f)["config"]["train"]["seed"] == k
    resume = [sys.executable, "-m", "aquarium_warp", "train", "--resume", str(out), "--iterations", "3", "--quiet"]
    done = subprocess.run(resume, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "resumed the population" in done.stdout and os.path.exists(out / "run-1" / "model_2.pt")
    with open(out / "run-0" / "progress.csv") as f:
        assert [line.split(",")[0] for line in f.read().splitlines()[1:]] == ["0", "1", "2"]


def test_groups_of_conditions_stack_into_one_env():
    from aquarium_warp import AquariumConfig

    a = AquariumConfig()
    b = dataclasses.replace(a, prey=dataclasses.replace(a.prey, view_distance=300.0))
    stacked = AquariumConfig.stack([a, b], 2)
    assert stacked.prey.view_distance == (a.prey.view_distance,) * 2 + (300.0, 300.0)
    with pytest.raises(ValueError, match="differ in width"):
        AquariumConfig.stack([a, dataclasses.replace(a, width=500.0)], 2)


def test_the_fused_stacked_gradients_are_each_runs_float64_gradients(device):
    """The fused kernels over a population's blocks of rows (Triton's interpreter on the CPU): each run's
    gradients of one mini-batch against the float64 gradients of its own learner alone on its own
    samples, within the fused loss's tolerance for one run (`test_fused_ppo.py`)."""
    pytest.importorskip("triton")
    from test_fused_ppo import GRADIENT_TOLERANCE, as_float64, gradients, relative

    from aquarium_warp.training import fused_mlp

    if device == "cpu" and not fused_mlp.INTERPRETED:
        pytest.skip("the fused kernels need CUDA or Triton's interpreter")
    configs = run_configs(base_config(), 3)
    per_run = rolled_out(configs)
    stacked = Population([dict(c, train={**c["train"], "device": device, "fused_mlp": True}) for c in configs],
                         stacked=True)  # fmt: skip
    copy_rollouts(per_run, stacked)
    indices, size = per_run.learner.mini_batch_indices()
    alg = stacked.learner
    for p in alg.actor.parameters():
        p.grad = None
    alg.fused_loss.step(alg._storage_indices(indices.to(stacked.device), size), 0, size)
    layers = {"actor": alg.actor.mlp, "critic": alg.critic.mlp}
    m = size // 3
    for k, run in enumerate(per_run.runs):
        own = indices.view(3, -1)[k]
        _, reference = gradients(as_float64(run), own, m)
        _, torch_grads = gradients(run, own, m)
        for name, ref in reference.items():
            part, _, layer, kind = name.split(".")  # e.g. actor.mlp.2.weight: the run's MLP's module 2
            stacked_param = (layers[part].weights if kind == "weight" else layers[part].biases)[int(layer) // 2]
            fused = stacked_param.grad[k].detach().double().cpu()
            assert relative(fused, ref) <= max(GRADIENT_TOLERANCE, 4 * relative(torch_grads[name], ref)), (k, name)
    per_run.close()
    stacked.close()


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_keeps_every_run_and_resume_continues_them_bit_for_bit(tmp_path, signum):
    """SIGINT or SIGTERM during `train --runs 2`: the command ends with the signal's code, every run's
    state of the last iteration is checkpointed, and `--resume` ends where an uninterrupted population
    ends (the same parameters, bit for bit on the CPU)."""
    out = tmp_path / "pop"
    argv = [sys.executable, "-m", "aquarium_warp", "train", "--preset", "tiny", "--runs", "2", "--num-worlds", "4",
            "--iterations", "400", "--log-dir", str(out), "--set", "runner.num_steps_per_env=8", "--set",
            "runner.save_interval=1", "--quiet", "--export", "none"]  # fmt: skip
    env = {**os.environ, "OMP_NUM_THREADS": "1", "GIT_PYTHON_REFRESH": "quiet"}
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # fmt: skip
    try:
        deadline = time.monotonic() + 300
        while not all((out / f"run-{k}" / "model_2.pt").exists() for k in range(2)):
            assert time.monotonic() < deadline and proc.poll() is None, "no checkpoints"
            time.sleep(0.05)
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signum, err
    assert f"train --resume {out}" in err
    done = [max(int(n[6:-3]) for n in os.listdir(out / f"run-{k}") if n.startswith("model_")) for k in range(2)]
    assert done[0] == done[1] and done[0] >= 2  # both runs saved at the iteration it stopped after
    total = done[0] + 3
    resume = subprocess.run([sys.executable, "-m", "aquarium_warp", "train", "--resume", str(out), "--iterations",
                             str(total), "--quiet"], capture_output=True, text=True, env=env, timeout=300)  # fmt: skip
    assert resume.returncode == 0, resume.stderr
    configs = run_configs(make_config("tiny", {"train": {"num_worlds": 4, "iterations": total, "quiet": True,
                                                         "export": ["jit", "onnx"]},
                                               "runner": {"num_steps_per_env": 8, "save_interval": 1}}), 2)  # fmt: skip
    whole = Population(configs, stacked=False)
    whole.train()
    for k in range(2):
        last = torch.load(out / f"run-{k}" / f"model_{total - 1}.pt", weights_only=False)
        assert_same(last["actor_state_dict"], dict(whole.runs[k].actor.state_dict()), f"resumed run {k}")
    whole.close()


def test_a_resume_refuses_a_run_folder_holding_another_runs_checkpoint(tmp_path):
    """A checkpoint of another population's run copied into run 1's folder is not continued."""
    import shutil

    ours = Population(run_configs(base_config(iterations=2), 2), log_dir=str(tmp_path / "ours"), stacked=False)
    ours.train()
    ours.close()
    theirs = Population(run_configs(base_config(iterations=2), 2), log_dir=str(tmp_path / "theirs"), stacked=False)
    theirs.train()
    theirs.close()
    with open(tmp_path / "ours" / "run-1" / "config.json") as f:
        assert json.load(f)["run_id"] != ours.run_ids[0]  # each run its own id
    shutil.copy(tmp_path / "theirs" / "run-1" / "model_1.pt", tmp_path / "ours" / "run-1" / "model_7.pt")
    with pytest.raises(ValueError, match="is of another run") as error:
        resume_population(str(tmp_path / "ours"), {"train": {"iterations": 10}})
    assert "\n" not in str(error.value)


def test_a_failed_runs_actions_stay_in_range(device):
    """A run whose network went NaN (before the population stops it) still acts within the action set,
    through torch's sampler and the fused kernel (9 actions: the kernel pads them to 16 columns)."""
    pytest.importorskip("triton")
    from aquarium_warp.training import fused_mlp

    for fused in (False, True):
        if fused and device == "cpu" and not fused_mlp.INTERPRETED:
            continue
        configs = run_configs(base_config(), 2)
        for config in configs:
            config["env"]["action_count"] = 9
            config["train"].update(device=device, fused_mlp=fused)
        population = Population(configs, stacked=True)
        with torch.no_grad():
            for p in population.runs[1].actor.parameters():
                p.fill_(float("nan"))
        v = population.vec_env
        with torch.inference_mode():
            population.learner.act_into(v.get_observations(), v.actions_buffer)
        actions = v.actions_buffer
        assert int(actions.min()) >= 0 and int(actions.max()) < 9, (fused, actions)
        population.close()

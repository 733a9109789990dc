"""The fused PPO loss (`training/fused_ppo.py`) against rsl-rl's loss through autograd, on the CPU
through Triton's interpreter (tests/conftest.py sets `TRITON_INTERPRET=1`), and on CUDA with
AQUARIUM_TEST_DEVICE=cuda:N.

The reference is rsl-rl's own mini-batch loss (`AquariumPPO._mini_batch_step`, torch's MLPs) in
float64; the fused kernels' gradients must be within float32 rounding of it, as torch's float32
gradients are. Measured under the interpreter over CASES: fused <= 4.4e-7, torch's float32 <= 5.2e-7.
"""

import copy
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

import pytest

pytest.importorskip("triton")  # the fused kernels (the `fused` extra)

import torch

from aquarium_warp.training import Trainer, fused_mlp, fused_ppo
from aquarium_warp.training.fused_mlp import FusedMLP, stacked_mlp_spec
from aquarium_warp.training.fused_ppo import FusedAct, FusedPPOLoss
from aquarium_warp.training.models import BatchedMLP
from aquarium_warp.training.ppo import flat_samples

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))
import bench_fused_update as bench  # noqa: E402  (builds learners, fills storage as a rollout would)

GRADIENT_TOLERANCE = 2e-6  # relative to the float64 gradient's largest magnitude; measured <= 4.4e-7
UPDATE_TOLERANCE = 1e-5  # one whole update, against float64 (see the test); measured <= 2.4e-6

# (clipped value loss, advantages normalised per mini-batch, spread of the old log-probabilities around
# the current ones: 0 puts every ratio at 1 (the surrogates tie), 0.3 clips many of them)
CASES = [(False, False, 0.0), (True, False, 0.1), (False, True, 0.3), (True, True, 0.3)]


@pytest.fixture
def interpreter() -> None:
    if not fused_mlp.INTERPRETED:
        pytest.skip("Triton's interpreter is off (AQUARIUM_TEST_DEVICE=cuda): see the cuda tests")


def learner(device: str = "cpu", worlds: int = 4, spread: float = 0.1, seed: int = 0, sharing: str = "parameter"):
    """The tiny preset's learner (torch's MLPs) with a filled storage; old log-probabilities spread
    around the current policy's by `spread` (normal noise). `sharing="individual"`: Individual
    Learning's 4 prey slots, so 4 networks per model (`BatchedMLP`)."""
    from aquarium_warp.training import make_config

    changes = {"train": {"num_worlds": worlds, "device": device, "quiet": True, "export": [], "fused_mlp": False,
                         "sharing": sharing}}  # fmt: skip
    alg = Trainer(make_config("tiny", changes)).runner.alg
    bench.fill_storage(alg, seed)
    gen = torch.Generator(device=alg.device).manual_seed(seed + 1)
    noise = torch.randn(alg.storage.actions_log_prob.shape, generator=gen, device=alg.device)
    alg.storage.actions_log_prob.add_(spread * noise)
    return alg


def use_fused(alg) -> None:
    """The learner's models as the fused kernels see them (Individual Learning's `BatchedMLP` keeps
    its modules and gets their spec) and its fused loss."""
    for model in (alg.actor, alg.critic):
        if isinstance(model.mlp, BatchedMLP):
            model.mlp.spec = stacked_mlp_spec(model.mlp)
        else:
            model.mlp = FusedMLP(model.mlp)
    alg.fused_loss = FusedPPOLoss(alg)


def gradients(alg, indices, size) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """`[value loss, surrogate, entropy]` and every parameter's gradient of mini-batch 0: from the fused
    loss where `alg.fused_loss` is set, else from rsl-rl's loss through autograd (no optimizer step)."""
    for model in (alg.actor, alg.critic):
        for p in model.parameters():
            p.grad = None
    if alg.fused_loss is not None:
        losses = alg.fused_loss.step(indices, 0, size)
    else:
        batch = indices[:size]
        obs, actions, values, returns, log_probs, advantages, params = flat_samples(alg.storage)
        step = alg._apply_gradients
        alg._apply_gradients = lambda: None  # the gradients as the loss leaves them
        try:
            losses = alg._mini_batch_step(
                obs[batch], actions[batch], values[batch], advantages[batch], returns[batch], log_probs[batch],
                tuple(p[batch] for p in params),
            )  # fmt: skip
        finally:
            alg._apply_gradients = step
    grads = {f"{n}.{k}": p.grad.detach().double().clone() for n, m in (("actor", alg.actor), ("critic", alg.critic))
             for k, p in m.named_parameters()}  # fmt: skip
    return losses, grads


def as_float64(alg):
    """A float64 copy of the learner (models and storage)."""
    ref = copy.deepcopy(alg)
    ref.actor.double()
    ref.critic.double()
    st = ref.storage
    for key in list(st.observations.keys()):
        st.observations[key] = st.observations[key].double()
    for name in ("actions", "actions_log_prob", "advantages", "values", "returns"):
        setattr(st, name, getattr(st, name).double())
    st.distribution_params = tuple(p.double() for p in st.distribution_params)
    return ref


def learner_tensors(alg) -> list[torch.Tensor]:
    """The parameters and the optimizer's state tensors (what an update changes), in a fixed order."""
    params = [p for model in (alg.actor, alg.critic) for p in model.parameters()]
    state = [v for p in params for v in alg.optimizer.state.get(p, {}).values() if isinstance(v, torch.Tensor)]
    return params + state


def snapshot(alg) -> list[torch.Tensor]:
    return [t.detach().clone() for t in learner_tensors(alg)]


def restore_in_place(alg, saved: list[torch.Tensor]) -> None:
    """Back to `saved`, into the same tensors (a captured graph keeps their addresses)."""
    with torch.no_grad():
        for t, v in zip(learner_tensors(alg), saved):
            t.copy_(v)


def relative(a: torch.Tensor, ref: torch.Tensor) -> float:
    return float((a - ref).abs().max() / ref.abs().max())


@pytest.mark.parametrize("sharing", ["parameter", "individual"])
@pytest.mark.parametrize("clipped_value,normalize,spread", CASES)
def test_gradients_equal_rsl_rl_loss_within_float32_rounding(clipped_value, normalize, spread, sharing, interpreter):
    """Every parameter's gradient within float32 rounding of rsl-rl's loss in float64; for Individual
    Learning's stacked networks (a program per network's rows, weights stored `[networks, in, out]`)
    network by network, each gradient laid out as its parameter (CUDA's fused Adam refuses others)."""
    alg = learner(spread=spread, sharing=sharing)
    alg.use_clipped_value_loss, alg.normalize_advantage_per_mini_batch = clipped_value, normalize
    torch.manual_seed(0)
    indices, size = alg.mini_batch_indices()
    reference_losses, reference = gradients(as_float64(alg), indices, size)
    torch_losses, torch_grads = gradients(alg, indices, size)
    use_fused(alg)
    losses, fused_grads = gradients(alg, indices, size)
    assert len(fused_grads) == 12
    assert all(p.grad.stride() == p.stride() for m in (alg.actor, alg.critic) for p in m.parameters())
    networks = 4 if sharing == "individual" else 1  # (the tiny preset's prey slots)
    assert alg.minibatch_group_size == networks

    def parts(t: torch.Tensor):
        return t.unbind(0) if networks > 1 else (t,)

    for name, ref in reference.items():
        assert fused_grads[name].shape == ref.shape
        for fused, part, torch_part in zip(parts(fused_grads[name]), parts(ref), parts(torch_grads[name])):
            assert part.abs().max() > 0, name  # every parameter (of every network) takes part
            assert relative(fused, part) <= max(GRADIENT_TOLERANCE, 4 * relative(torch_part, part)), name
    assert torch.allclose(losses, reference_losses, rtol=1e-5, atol=1e-7)
    assert torch.allclose(torch_losses, reference_losses, rtol=1e-5, atol=1e-7)


def test_ties_and_clipping_hand_checked(interpreter):
    """Every ratio at 1 (old log-probabilities equal the current ones): the surrogates tie and the clamp
    passes, so the actor's gradient is that of -mean(advantage * ratio) - entropy_coef * entropy; with
    every ratio far outside the clip range the surrogate's gradient vanishes where the clipped branch
    is the larger, leaving (for a zero entropy weight) no gradient where every row is clipped that way."""
    alg = learner(spread=0.0)
    use_fused(alg)
    alg.entropy_coef = 0.0
    indices, size = alg.mini_batch_indices()
    _, at_one = gradients(alg, indices, size)
    assert all(at_one[f"actor.mlp.{i}.weight"].abs().max() > 0 for i in (0, 2, 4))
    # advantages > 0 and ratios far above 1 + clip: -A*clamp(r) > -A*r, the max takes the clipped branch,
    # whose clamp passes no gradient: the actor's gradient is exactly zero.
    alg.storage.advantages.abs_().add_(0.1)
    alg.storage.actions_log_prob.sub_(5.0)
    _, clipped = gradients(alg, indices, size)
    assert all(torch.count_nonzero(clipped[k]) == 0 for k in clipped if k.startswith("actor."))
    assert all(clipped[k].abs().max() > 0 for k in clipped if k.startswith("critic."))


@pytest.mark.slow
def test_whole_update_equals_torch_and_is_deterministic(interpreter):
    """A whole `update_on_device` (4 epochs x 4 mini-batches) from the same state: with the fused MLPs
    (loss through autograd) and with the fused loss, every parameter is as close to rsl-rl's float64
    update as torch's float32 update is (Adam's first steps turn a rounding difference in a near-zero
    gradient element into up to 2 learning rates, so the bound is relative to torch's own float32
    error; measured: fused loss <= 2.4e-6, torch's float32 <= 2.8e-6); twice the same: bit-identical."""
    alg = learner()
    reference = as_float64(alg)
    torch.manual_seed(0)
    indices, size = alg.mini_batch_indices()
    switch = bench.MLPSwitch(alg)
    after = {path: bench.parameters_after_update(switch, path, indices, size) for path in bench.PATHS}
    reference.update_on_device(indices, size)
    ref = {f"{n}.{k}": v.detach() for n, m in (("actor", reference.actor), ("critic", reference.critic))
           for k, v in m.state_dict().items()}  # fmt: skip
    assert len(ref) == 12
    for name, value in ref.items():
        torch_error = relative(after["torch"][name].double(), value)
        for path in ("fused-mlp", "fused"):
            assert relative(after[path][name].double(), value) <= max(UPDATE_TOLERANCE, 4 * torch_error), (path, name)
    again = bench.parameters_after_update(switch, "fused", indices, size)
    assert all(torch.equal(after["fused"][k], again[k]) for k in again)


@pytest.mark.parametrize(
    "change,reason",
    [
        ({"actor_normalization": True}, "observation normalisation"),
        ({"use_mixed_precision": True}, "mixed precision"),
        ({"schedule": "adaptive"}, "adaptive learning-rate schedule"),
        ({"torch_mlp": True}, "must be FusedMLPModel"),
    ],
)
def test_unsupported_learners_keep_the_autograd_path(change, reason, interpreter):
    alg = learner()
    use_fused(alg)
    if change.get("actor_normalization"):
        alg.actor.obs_normalization = True
    if change.get("use_mixed_precision"):
        alg.use_mixed_precision = True
    if change.get("schedule"):
        alg.schedule, alg.desired_kl = "adaptive", 0.01
    if change.get("torch_mlp"):
        alg.critic.mlp = torch.nn.Sequential(*alg.critic.mlp)
    assert reason in FusedPPOLoss.unsupported(alg)
    with pytest.raises(ValueError, match=f"^FusedPPOLoss: .*{reason}"):
        FusedPPOLoss(alg)


def test_individual_learning_fused_step_equals_rsl_rl_act(interpreter):
    alg = learner(worlds=6, sharing="individual")
    alg.storage.clear()
    use_fused(alg)
    alg.fused_act = FusedAct(alg)
    check_fused_act(alg)


def acting_learner(device: str, worlds: int = 4):
    """The tiny preset's learner with fused MLPs and the fused rollout step, its storage empty."""
    alg = bench.build("tiny", worlds, device)
    use_fused(alg)
    alg.fused_act = FusedAct(alg)
    return alg


ACT_TOLERANCE = 1e-5  # float32 log-probabilities and values of one MLP forward against float64


def check_fused_act(alg, tf32: bool = False) -> None:
    """One step of `FusedAct` against rsl-rl's `act` and `process_env_step` on the same observations:
    the generator advances as rsl-rl's sampler advances it; the stored observations, dones and
    bootstrapped rewards are rsl-rl's bit for bit; the log-probabilities, values and the chosen
    log-probability are float64's within float32 rounding (TF32's, with `tf32`); the action is the
    argmax of the float64 probabilities over the same Exp(1) noise (wherever the top two scores are
    not within rounding of each other), also in the adapter's int32 buffer."""
    from tensordict import TensorDict

    device = torch.device(alg.device)
    storage = alg.storage
    N, K = storage.num_envs, alg.actor.mlp.spec.dims[-1]
    gen = torch.Generator(device=device).manual_seed(3)
    obs = TensorDict({"policy": 2 * torch.randn(N, storage.observations["policy"].shape[-1], generator=gen,
                                                 device=device)}, batch_size=[N])  # fmt: skip
    rng = torch.cuda.get_rng_state(device) if device.type == "cuda" else torch.get_rng_state()
    set_rng = (lambda s: torch.cuda.set_rng_state(s, device)) if device.type == "cuda" else torch.set_rng_state
    draw = (lambda: torch.cuda.get_rng_state(device)) if device.type == "cuda" else torch.get_rng_state
    noise = torch.empty(N, K, device=device).exponential_(1)
    env_actions = torch.full((N // 2, 2), -1, dtype=torch.int32, device=device)
    set_rng(rng)
    with torch.inference_mode():
        alg.act_into(obs, env_actions)
    after_fused = draw()
    set_rng(rng)
    with torch.inference_mode():
        super(type(alg), alg).act(obs)  # rsl-rl's own act: its sampler's draws
    assert torch.equal(draw(), after_fused)
    t = storage.step
    assert t == 0
    actor64, critic64 = copy.deepcopy(alg.actor.mlp).double(), copy.deepcopy(alg.critic.mlp).double()
    x64 = obs["policy"].double()
    with torch.no_grad():
        log_probs = torch.log_softmax(actor64(x64), dim=-1)
        values = critic64(x64)
    tolerance = 1e-2 if tf32 else ACT_TOLERANCE
    assert torch.equal(storage.observations["policy"][t], obs["policy"])
    stored_log_probs = storage.distribution_params[0][t].double()
    assert float((stored_log_probs - log_probs).abs().max()) <= tolerance * float(log_probs.abs().max())
    assert float((storage.values[t].double() - values).abs().max()) <= tolerance * float(values.abs().max())
    scores = log_probs.exp() / noise.double()
    top2 = scores.topk(2, dim=-1).values
    clear = (top2[:, 0] - top2[:, 1]) > 1e-4 * top2[:, 0]
    assert int(clear.sum()) > N // 2
    actions = storage.actions[t].view(-1)
    assert torch.equal(actions[clear].long(), scores.argmax(dim=-1)[clear])
    assert torch.equal(env_actions.view(-1), actions.to(torch.int32))
    chosen = stored_log_probs.gather(1, actions.long().view(-1, 1)).view(-1)
    assert torch.equal(storage.actions_log_prob[t].view(-1).double(), chosen)
    rewards = torch.randn(N, generator=gen, device=device)
    dones = (torch.rand(N, generator=gen, device=device) < 0.3).long()
    time_outs = torch.rand(N, generator=gen, device=device) < 0.5
    alg.process_env_step(obs, rewards, dones, {"time_outs": time_outs})
    want = rewards.clone()
    want += alg.gamma * torch.squeeze(storage.values[t] * time_outs.unsqueeze(1), 1)  # rsl-rl's bootstrap
    assert torch.equal(storage.rewards[t].view(-1), want)
    assert torch.equal(storage.dones[t].view(-1), dones)
    assert storage.step == 1


def test_fused_act_equals_rsl_rl_act(interpreter):
    check_fused_act(acting_learner("cpu"))


@pytest.mark.parametrize("tf32", [False, True])
@pytest.mark.parametrize("sharing", ["parameter", "individual"])
def test_cuda_fused_act_equals_rsl_rl_act(cuda_device, tf32, sharing):
    allow_tf32 = torch.backends.cuda.matmul.allow_tf32
    torch.backends.cuda.matmul.allow_tf32 = tf32
    try:
        if sharing == "parameter":
            alg = acting_learner(cuda_device, worlds=256)
        else:
            alg = learner(cuda_device, worlds=256, sharing="individual")
            alg.storage.clear()
            use_fused(alg)
            alg.fused_act = FusedAct(alg)
        check_fused_act(alg, tf32)
    finally:
        torch.backends.cuda.matmul.allow_tf32 = allow_tf32


def test_cuda_individual_learning_gradients(cuda_device):
    """On CUDA (float32 products as three TF32 products): Individual Learning's fused gradients against
    rsl-rl's loss through `BatchedMLP` in float64, network by network."""
    alg = learner(cuda_device, worlds=64, sharing="individual")
    torch.manual_seed(0)
    indices, size = alg.mini_batch_indices()
    _, reference = gradients(as_float64(alg), indices, size)
    use_fused(alg)
    _, fused_grads = gradients(alg, indices, size)
    for name, ref in reference.items():
        for network in range(alg.actor.mlp.groups):
            assert relative(fused_grads[name][network], ref[network]) <= GRADIENT_TOLERANCE, (name, network)


def test_fused_act_refuses_mismatched_buffers(interpreter):
    """Observations or an action buffer of another size than the storage's rows: a one-line error
    before the kernel (which would read or write past them), and the learner still acts after."""
    from tensordict import TensorDict

    alg = acting_learner("cpu")
    N, L = alg.storage.num_envs, alg.storage.observations["policy"].shape[-1]
    for obs, buffer, message in [
        (torch.zeros(N - 1, L), None, "observations"),
        (torch.zeros(N, L + 1), None, "observations"),
        (torch.zeros(N, L), torch.zeros(N - 2, dtype=torch.int32), "env_actions"),
    ]:
        with pytest.raises(ValueError, match=f"^FusedAct: {message}") as info:
            alg.fused_act.act(TensorDict({"policy": obs}, batch_size=[obs.shape[0]]), buffer)
        assert "\n" not in str(info.value)
    assert alg.storage.step == 0
    alg.fused_act.act(TensorDict({"policy": torch.zeros(N, L)}, batch_size=[N]))


def test_fused_act_unsupported_learners(interpreter):
    """Where the fused loss does not serve, nor does the fused step; nor with a critic of another
    observation group than the actor's."""
    alg = acting_learner("cpu")
    assert FusedAct.unsupported(alg) is None
    alg.critic.obs_groups = ["team"]
    assert "one observation group" in FusedAct.unsupported(alg)
    alg = acting_learner("cpu")
    alg.schedule, alg.desired_kl = "adaptive", 0.01
    assert FusedAct.unsupported(alg) == FusedPPOLoss.unsupported(alg)
    with pytest.raises(ValueError, match="^FusedAct: .*adaptive"):
        FusedAct(alg)


@pytest.mark.slow
def test_individual_learning_trains_fused_and_records_it(tmp_path, interpreter):
    """`train.fused_mlp` with `sharing = "individual"`: the learner's models are
    `FusedIndividualMLPModel`, its update runs the fused loss and its rollout the fused step, and
    config.json says so; a checkpoint of it loads into the unfused Individual Learning models."""
    from aquarium_warp.training import make_config
    from aquarium_warp.training.models import IndividualMLPModel

    changes = {"train": {"num_worlds": 4, "iterations": 1, "fused_mlp": True, "sharing": "individual",
                         "quiet": True, "export": []}}  # fmt: skip
    trainer = Trainer(make_config("tiny", changes), log_dir=str(tmp_path / "fused"))
    alg = trainer.runner.alg
    assert type(alg.actor).__name__ == "FusedIndividualMLPModel" and alg.actor.mlp.spec.groups == 4
    assert isinstance(alg.fused_loss, FusedPPOLoss) and isinstance(alg.fused_act, FusedAct)
    trainer.train(1)
    exported = trainer.export(formats=["jit"])["jit"]  # TorchScript leaves the kernels' spec out
    trainer.close()
    assert os.path.getsize(exported) > 0
    record = json.loads((tmp_path / "fused" / "config.json").read_text())
    assert record["fused_loss"] == record["fused_act"] == {"prey": True}
    checkpoint = torch.load(tmp_path / "fused" / "model_0.pt", weights_only=False)
    plain = Trainer(make_config("tiny", {"train": {**changes["train"], "fused_mlp": False}}))
    assert type(plain.runner.alg.actor) is IndividualMLPModel
    plain.runner.alg.actor.load_state_dict(checkpoint["actor_state_dict"])
    plain.close()


@pytest.mark.slow
def test_both_teams_use_the_fused_loss(tmp_path, interpreter):
    """Both teams learning with `train.fused_mlp`: each learner's update runs the fused loss."""
    from aquarium_warp.training import make_config

    changes = {
        "train": {"num_worlds": 2, "iterations": 1, "fused_mlp": True, "team": "both", "quiet": True, "export": []}
    }
    trainer = Trainer(make_config("tiny", changes), log_dir=str(tmp_path))
    assert all(isinstance(learner.alg.fused_loss, FusedPPOLoss) for learner in trainer.runner.learners)
    trainer.train(1)
    trainer.close()
    record = json.loads((tmp_path / "config.json").read_text())
    assert record["fused_loss"] == record["fused_act"] == {"prey": True, "predator": True}


@pytest.mark.slow
def test_trainer_uses_the_fused_loss_and_records_it(tmp_path, interpreter):
    """`train.fused_mlp` on: the learner's update runs the fused loss, and config.json says so; with the
    adaptive schedule it keeps autograd through the fused MLPs, and config.json says why."""
    from aquarium_warp.training import make_config

    changes = {"train": {"num_worlds": 4, "iterations": 1, "fused_mlp": True, "quiet": True, "export": []}}
    trainer = Trainer(make_config("tiny", changes), log_dir=str(tmp_path / "fused"))
    assert isinstance(trainer.runner.alg.fused_loss, FusedPPOLoss)
    trainer.train(1)
    trainer.close()
    record = json.loads((tmp_path / "fused" / "config.json").read_text())
    assert record["fused_loss"] == record["fused_act"] == {"prey": True}
    adaptive = {"runner": {"algorithm": {"schedule": "adaptive", "desired_kl": 0.01}}}
    trainer = Trainer(make_config("tiny", changes, adaptive), log_dir=str(tmp_path / "adaptive"))
    assert trainer.runner.alg.fused_loss is None and trainer.runner.alg.fused_act is None
    trainer.close()
    record = json.loads((tmp_path / "adaptive" / "config.json").read_text())
    assert "adaptive learning-rate schedule" in record["fused_loss"]["prey"]


@pytest.mark.parametrize("tf32", [False, True])
def test_cuda_gradients_and_graph_replay(cuda_device, tf32):
    """On CUDA: the fused loss's gradients against rsl-rl's float64 loss (float32 products as three
    TF32 products; or TF32, within its rounding), and a whole update captured in a CUDA graph after an
    eager one gives, replayed, what an eager update from the same state gives."""
    allow_tf32 = torch.backends.cuda.matmul.allow_tf32
    torch.backends.cuda.matmul.allow_tf32 = tf32
    try:
        alg = learner(device=cuda_device, worlds=64)
        torch.manual_seed(0)
        indices, size = alg.mini_batch_indices()
        _, reference = gradients(as_float64(alg), indices, size)
        switch = bench.MLPSwitch(alg)
        switch.use("fused")
        _, fused_grads = gradients(alg, indices, size)
        for name, ref in reference.items():
            assert relative(fused_grads[name], ref) <= (1e-2 if tf32 else GRADIENT_TOLERANCE), name
        side = torch.cuda.Stream(torch.device(cuda_device))
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            alg.update_on_device(indices, size)  # eager warm-up on the capturing stream: optimizer state made
            graph = torch.cuda.CUDAGraph()
            with torch.cuda.graph(graph, stream=side):
                alg.update_on_device(indices, size)
            start = snapshot(alg)
            graph.replay()
            replayed = snapshot(alg)
            restore_in_place(alg, start)
            alg.update_on_device(indices, size)
            eager = snapshot(alg)
        torch.cuda.synchronize()
        assert len(eager) == len(replayed) > 12 and not all(torch.equal(a, b) for a, b in zip(start, eager))
        assert all(torch.equal(a, b) for a, b in zip(eager, replayed))
    finally:
        torch.backends.cuda.matmul.allow_tf32 = allow_tf32


@pytest.mark.slow
def test_tune_fused_kernels_runs_on_the_cpu(tmp_path, interpreter, staged_copy):
    """benchmarks/tune_fused_kernels.py under the interpreter: one shape timed and recorded with its
    provenance, the module settings restored after."""
    import tune_fused_kernels

    settings = (fused_mlp.block_rows, fused_mlp.NUM_WARPS, fused_mlp.PROGRAMS_PER_SM, fused_mlp.FAST_TANH_WITH_TF32)
    out = tmp_path / "tune.json"
    act_settings = (fused_ppo.block_rows, fused_ppo.NUM_WARPS)
    argv = ["--device", "cpu", "--preset", "tiny", "--worlds", "2", "--rows", "16,32", "--warps", "4"]
    argv += ["--act-rows", "16,32", "--act-warps", "4"]
    assert (
        tune_fused_kernels.main(argv + ["--programs", "2", "--repeats", "1", "--out", str(out), "--commit", "abc123"])
        == 0
    )
    data = json.loads(out.read_text())
    assert data["git"]["commit"] == "abc123" and data["worlds"] == 2 and data["tf32"] is False
    assert [(s["rows"], s["warps"], s["programs_per_sm"]) for s in data["shapes"]] == [(16, 4, 2), (32, 4, 2)]
    assert all(s["ms"] > 0 for s in data["shapes"])
    assert [(s["rows"], s["warps"]) for s in data["act_shapes"]] == [(16, 4), (32, 4)]
    assert all(s["ms"] > 0 for s in data["act_shapes"])
    assert (
        fused_mlp.block_rows,
        fused_mlp.NUM_WARPS,
        fused_mlp.PROGRAMS_PER_SM,
        fused_mlp.FAST_TANH_WITH_TF32,
    ) == settings
    assert (fused_ppo.block_rows, fused_ppo.NUM_WARPS) == act_settings
    with pytest.raises(SystemExit):
        tune_fused_kernels.main(["--device", "cpu", "--rows", "48"])  # not a power of two


@pytest.mark.slow
def test_every_fused_kernel_compiles_for_cuda_without_a_gpu():
    """Triton's code generator and ptxas take every fused kernel (float32 and TF32 with the inline tanh)
    for sm_90: what the interpreter runs, the GPU can compile."""
    import subprocess

    env = {k: v for k, v in os.environ.items() if k != "TRITON_INTERPRET"}
    script = Path(__file__).with_name("compile_fused_kernels.py")
    done = subprocess.run([sys.executable, str(script), "90"], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    lines = [line for line in done.stdout.splitlines() if "bytes of cubin" in line]
    assert len(lines) == 16, done.stdout  # two MLP kernels, three PPO kernels for one and for 6 networks; 2 precisions

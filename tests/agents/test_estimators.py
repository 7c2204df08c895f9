"""Estimators: shapes, batched equals member by member, MC samples differ, modes restored, seeds."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from oodmon.agents.estimators import EnsembleEstimator, MCEstimator, _TorchPart
from oodmon.agents.layers import DropConnectLinear, add_dropout, mc_sampling, to_dropconnect
from oodmon.agents.networks import build_modules
from oodmon.agents import plan
from oodmon.agents.plan import active_inputs, bernoulli_positions, repeat_rows
from oodmon.errors import ConfigError, InvalidParameterError

OBS = np.random.default_rng(0).normal(size=(7, 4)).astype(np.float32)


def _mlp(seed: int, out: int = 2, tanh: bool = False) -> nn.Sequential:
    torch.manual_seed(seed)
    layers = [nn.Linear(4, 32), nn.ReLU(), nn.Linear(32, 32), nn.ReLU(), nn.Linear(32, out)]
    return nn.Sequential(*layers, *([nn.Tanh()] if tanh else []))


def _mc(method: str, **kwargs) -> MCEstimator:
    transform = add_dropout if method == "dropout" else to_dropconnect
    return MCEstimator(transform(_mlp(0), 0.2), **kwargs)


@pytest.mark.parametrize("method", ["dropout", "dropconnect"])
def test_mc_shapes_and_greedy_action_of_the_mean(method):
    estimate = _mc(method, n_samples=20, seed=1).estimate(OBS)
    assert estimate.samples.shape == (20, 7, 2)
    assert estimate.mean.shape == estimate.std.shape == (7, 2)
    np.testing.assert_allclose(estimate.mean, estimate.samples.mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(estimate.std, estimate.samples.std(axis=0), rtol=1e-5, atol=1e-7)
    np.testing.assert_array_equal(estimate.action, estimate.mean.argmax(axis=1))
    # The K samples differ from one another: they are samples, not copies.
    assert len({s.tobytes() for s in estimate.samples}) == 20
    assert (estimate.std > 0).all()


@pytest.mark.parametrize("method", ["dropout", "dropconnect"])
def test_seeded_sampling_is_reproducible_and_leaves_the_global_generator_alone(method):
    first, again, other = _mc(method, seed=7), _mc(method, seed=7), _mc(method, seed=8)
    torch.manual_seed(123)
    before = torch.get_rng_state()
    a = first.estimate(OBS).samples
    assert torch.equal(torch.get_rng_state(), before)
    b, c = again.estimate(OBS).samples, other.estimate(OBS).samples
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("method", ["dropout", "dropconnect"])
@pytest.mark.parametrize("start_mode", [True, False], ids=["train", "eval"])
def test_sampling_a_sequential_never_changes_the_models_mode(method, start_mode):
    estimator = _mc(method, seed=0, obs_shape=(4,))
    net = estimator.network.train(start_mode)
    estimator.estimate(OBS)
    assert all(m.training == start_mode for m in net.modules())
    with pytest.raises(InvalidParameterError, match=r"observations of shape \(5,\) are not allowed; this estimator takes \(4,\)"):
        estimator.estimate(np.zeros((3, 5), np.float32))
    assert all(m.training == start_mode for m in net.modules())


class Exploding(nn.Module):
    """A user's network (not a Sequential) that fails inside its forward pass on request."""

    def __init__(self) -> None:
        super().__init__()
        self.body, self.drop, self.out = nn.Linear(4, 16), nn.Dropout(0.3), nn.Linear(16, 2)
        self.explode = False

    def forward(self, x):
        h = self.drop(torch.relu(self.body(x)))
        if self.explode:
            raise RuntimeError("boom")
        return self.out(h)


@pytest.mark.parametrize("start_mode", [True, False], ids=["train", "eval"])
def test_torch_sampling_restores_the_mode_also_after_an_exception(start_mode):
    net = Exploding().train(start_mode)
    estimator = MCEstimator(net, n_samples=10, seed=0)
    assert (estimator.estimate(OBS).std > 0).all()
    assert all(m.training == start_mode for m in net.modules())
    net.explode = True
    with pytest.raises(RuntimeError, match="boom"):
        estimator.estimate(OBS)
    assert all(m.training == start_mode for m in net.modules())


def test_mc_sampling_turns_on_only_the_stochastic_layers():
    net = add_dropout(_mlp(0), 0.3).eval()
    with mc_sampling(net):
        assert [m.training for m in net] == [False, False, True, False, False, True, False]


def test_dropconnect_drops_weights_not_activations():
    torch.manual_seed(0)
    layer = DropConnectLinear(50, 40, p=0.3, bias=False)
    x = torch.eye(50).unsqueeze(0).expand(10, 50, 50)  # row i of the output reads weight column i
    with torch.no_grad():
        out = layer.train()(x)  # (10 samples, 50, 40)
    effective = out.transpose(1, 2)  # (10, 40, 50): the weights each sample used
    kept = effective != 0
    assert kept.float().mean().item() == pytest.approx(0.7, abs=0.02)
    # Kept weights are the layer's weights scaled by 1/(1-p); dropped ones are exactly zero.
    torch.testing.assert_close(effective[kept], (layer.weight / 0.7).expand(10, 40, 50)[kept])
    # Each sample has its own mask, and an activation is not dropped as a whole: every output
    # unit of every sample still reads most of its inputs.
    assert not torch.equal(kept[0], kept[1])
    assert (kept.sum(dim=2) > 20).all()
    layer.eval()
    with torch.no_grad():
        torch.testing.assert_close(layer(torch.eye(50)), layer.weight.T)


def test_batched_ensemble_equals_member_by_member():
    members = [_mlp(seed) for seed in range(5)]
    estimate = EnsembleEstimator(members).estimate(OBS)
    with torch.no_grad():
        expected = np.stack([m(torch.as_tensor(OBS)).numpy() for m in members])
    np.testing.assert_allclose(estimate.samples, expected, atol=1e-6, rtol=0)
    np.testing.assert_array_equal(estimate.action, expected.mean(axis=0).argmax(axis=1))


@pytest.mark.parametrize("activation", [nn.LeakyReLU(0.05), nn.ELU(0.7), nn.SiLU(), nn.Sigmoid(), nn.GELU(),
                                        nn.GELU(approximate="tanh")], ids=repr)
def test_ensembles_of_other_activations_compute_the_modules_numbers(activation):
    # SB3 users pick activation_fn; such ensembles were refused (ReLU and Tanh only).
    def member(seed: int) -> nn.Sequential:
        torch.manual_seed(seed)
        return nn.Sequential(nn.Linear(4, 32), activation, nn.Linear(32, 32), activation, nn.Linear(32, 2))

    members = [member(seed) for seed in range(3)]
    wide = OBS * 10  # both sides of every activation's bend, and sigmoid's saturation
    estimate = EnsembleEstimator(members).estimate(wide)
    with torch.no_grad():
        expected = np.stack([m(torch.as_tensor(wide)).numpy() for m in members])
    np.testing.assert_allclose(estimate.samples, expected, atol=2e-5, rtol=1e-5)


def test_an_ensemble_of_members_whose_activations_differ_in_a_parameter_is_refused():
    members = [nn.Sequential(nn.Linear(4, 8), nn.LeakyReLU(slope), nn.Linear(8, 2)) for slope in (0.01, 0.2)]
    with pytest.raises(ConfigError, match=r"member 1 has another architecture.*LeakyReLU\(negative_slope=0.2\)"):
        EnsembleEstimator(members)
    with pytest.raises(ConfigError, match=r"ReLU, Tanh, LeakyReLU, ELU, SiLU, Sigmoid or GELU activations only; found Mish"):
        EnsembleEstimator([nn.Sequential(nn.Linear(4, 8), nn.Mish(), nn.Linear(8, 2))] * 2)


def test_actions_are_scaled_to_the_action_space_and_the_mean_is_deployed():
    members = [_mlp(seed, out=1, tanh=True) for seed in range(5)]
    estimate = EnsembleEstimator(members, kind="actions", action_low=[-2.0], action_high=[2.0]).estimate(OBS)
    with torch.no_grad():
        expected = 2.0 * np.stack([m(torch.as_tensor(OBS)).numpy() for m in members])
    np.testing.assert_allclose(estimate.samples, expected, atol=1e-6)
    np.testing.assert_allclose(estimate.action, expected.mean(axis=0), atol=1e-6)
    assert np.abs(estimate.samples).max() <= 2.0


def test_single_observation_is_a_batch_of_one():
    estimate = EnsembleEstimator([_mlp(s) for s in range(3)]).estimate(OBS[0])
    assert estimate.samples.shape == (3, 1, 2) and estimate.action.shape == (1,)


def test_estimator_errors_name_the_problem():
    with pytest.raises(ConfigError, match="has no dropout or DropConnect layer"):
        MCEstimator(_mlp(0))
    with pytest.raises(InvalidParameterError, match="n_samples=1 is not allowed"):
        MCEstimator(add_dropout(_mlp(0), 0.1), n_samples=1)
    with pytest.raises(ConfigError, match="at least 2 members; got 1"):
        EnsembleEstimator([_mlp(0)])
    with pytest.raises(ConfigError, match="member 1 has another architecture than member 0"):
        EnsembleEstimator([_mlp(0), _mlp(1, out=3)])
    with pytest.raises(ConfigError, match="needs action_low and action_high"):
        EnsembleEstimator([_mlp(0), _mlp(1)], kind="actions")
    with pytest.raises(InvalidParameterError, match="kind='values' is not allowed"):
        EnsembleEstimator([_mlp(0), _mlp(1)], kind="values")
    with pytest.raises(InvalidParameterError, match=r"drop probability p=1.0 is not allowed; it must satisfy 0 < p < 1"):
        add_dropout(_mlp(0), 1.0)


# p = 0.02 and 0.05 (the shipped CartPole and Pendulum agents') are below plan.SPARSE_BELOW: those
# layers draw the dropped positions, not a dense mask.
@pytest.mark.parametrize("p", [0.3, 0.02, 0.05], ids=["dense-mask", "dropped-positions", "dropped-positions-p0.05"])
def test_mc_dropconnect_estimator_samples_weight_masks_per_sample(p):
    torch.manual_seed(0)
    layer = DropConnectLinear(50, 40, p=p, bias=False)
    estimator = MCEstimator(nn.Sequential(layer), n_samples=10, seed=0)
    samples = estimator.estimate(np.eye(50, dtype=np.float32)).samples  # (10, 50 one-hot inputs, 40)
    effective = samples.transpose(0, 2, 1)  # (10, 40, 50): the weights each sampled network used
    kept = effective != 0
    assert kept.mean() == pytest.approx(1 - p, abs=5 * np.sqrt(p * (1 - p) / kept.size))  # 5 sigma
    weights = layer.weight.detach().numpy()
    np.testing.assert_allclose(effective[kept], np.broadcast_to(weights / (1 - p), effective.shape)[kept], rtol=1e-5, atol=1e-6)
    assert not np.array_equal(kept[0], kept[1])  # each sample its own mask


def test_dropped_positions_are_independent_bernoulli_trials():
    # 4,000 seeded draws of 300 trials at p = 0.3: every position succeeds with frequency p and
    # neighbours together with p^2 (independence), within 5 sigma; positions sorted, in range.
    p, size, draws = 0.3, 300, 4_000
    rng = np.random.default_rng(0)
    hits = np.zeros((draws, size), bool)
    for draw in range(draws):
        positions = bernoulli_positions(rng, size, p)
        assert np.all(np.diff(positions) > 0) and positions.min(initial=0) >= 0 and positions.max(initial=0) < size
        hits[draw, positions] = True
    sigma = np.sqrt(p * (1 - p) / draws)
    assert np.all(np.abs(hits.mean(0) - p) < 5 * sigma)
    pairs = (hits[:, :-1] & hits[:, 1:]).mean()
    assert pairs == pytest.approx(p * p, abs=5 * np.sqrt(p * p * (1 - p * p) / hits[:, 1:].size))
    assert len(bernoulli_positions(rng, 0, p)) == 0


@pytest.mark.parametrize(("p", "outputs"), [(0.1, 6), (0.02, 6), (0.02, 8)],
                         ids=["dense-mask", "dropped-positions", "dropped-positions-power-of-two-outputs"])
@pytest.mark.parametrize("zero_fraction", [0.0, 0.8, 1.0], ids=["dense", "mostly-zero", "all-zero"])
def test_dropconnect_samples_have_the_formulas_moments_when_inputs_are_zero(zero_fraction, p, outputs):
    # Masks are drawn only for inputs that are not zero (after a ReLU most are); the samples must
    # still have DropConnect's moments: y_j = b_j + sum_i x_i W_ij m_ij / (1 - p), m ~ Bernoulli(1 - p),
    # so E[y_j] = b_j + sum_i x_i W_ij and Var[y_j] = p / (1 - p) * sum_i (x_i W_ij)^2. The dropped
    # positions are decoded by a division, or by shifts when the layer's outputs are a power of two.
    rng = np.random.default_rng(0)
    torch.manual_seed(0)
    layer = DropConnectLinear(64, outputs, p=p)
    x = rng.uniform(0.5, 2.0, 64).astype(np.float32)
    x[rng.permutation(64)[: int(zero_fraction * 64)]] = 0.0
    samples = MCEstimator(nn.Sequential(layer), n_samples=40_000, seed=1).estimate(x).samples[:, 0].astype(np.float64)
    w, b = layer.weight.detach().numpy().astype(np.float64), layer.bias.detach().numpy()
    contributions = x[None, :] * w  # (outputs, 64)
    variance = p / (1 - p) * (contributions**2).sum(1)
    assert np.all(np.abs(samples.mean(0) - (b + contributions.sum(1))) <= 4 * np.sqrt(variance / 40_000) + 1e-6)
    np.testing.assert_allclose(samples.var(0), variance, rtol=0.05, atol=1e-9)


def test_mc_dropout_estimator_matches_the_dropout_formula():
    # One dropout layer before an identity-like linear layer: every output of every sample is the
    # input scaled by 1/(1-p) or 0, and about a fraction p are 0.
    linear = nn.Linear(200, 200, bias=False)
    with torch.no_grad():
        linear.weight.copy_(torch.eye(200))
    estimator = MCEstimator(nn.Sequential(nn.Dropout(0.25), linear), n_samples=50, seed=3)
    samples = estimator.estimate(np.ones(200, np.float32)).samples
    values = np.unique(samples)
    assert len(values) == 2 and values[0] == 0 and values[1] == pytest.approx(1 / 0.75)
    assert (samples == 0).mean() == pytest.approx(0.25, abs=0.01)


def test_actors_report_the_spread_before_their_tanh():
    members = [_mlp(seed, out=1, tanh=True) for seed in range(5)]
    estimate = EnsembleEstimator(members, kind="actions", action_low=[-2.0], action_high=[2.0]).estimate(OBS)
    with torch.no_grad():
        pre = np.stack([nn.Sequential(*list(m)[:-1])(torch.as_tensor(OBS)).numpy() for m in members])
    np.testing.assert_allclose(estimate.pre_squash_std, pre.std(axis=0), rtol=1e-5)
    np.testing.assert_allclose(estimate.samples, 2.0 * np.tanh(pre), atol=1e-6)
    # Saturation: members that all push hard agree after the tanh but not before it.
    for m, bias in zip(members, [3.0, 5.0, 8.0, 4.0, 6.0]):
        with torch.no_grad():
            m[-2].weight.zero_()
            m[-2].bias.fill_(bias)
    saturated = EnsembleEstimator(members, kind="actions", action_low=[-2.0], action_high=[2.0]).estimate(OBS)
    assert (saturated.std < 0.01).all() and (saturated.pre_squash_std > 1.5).all()
    q = EnsembleEstimator([_mlp(s) for s in range(3)]).estimate(OBS)
    assert q.pre_squash_std is None


def _cnn_torso() -> nn.Sequential:
    """Pong's torso (scaling and Nature CNN), as the zoo's bootstrapped ensemble has it."""
    torch.manual_seed(0)
    arch = {"algorithm": "dqn", "obs_shape": [4, 84, 84], "n_outputs": 6, "cnn": True, "n_members": 2,
            "shared_torso": True}
    return build_modules(arch)["torso"]


def test_a_cnn_torso_called_layer_by_layer_gives_the_modules_numbers():
    part = _TorchPart(_cnn_torso())
    assert part._chain is not None and len(part._chain) == 10  # scale, 3 x (conv, relu), flatten, linear, relu
    batch = np.random.default_rng(0).integers(0, 256, size=(2, 4, 84, 84)).astype(np.float32)
    with torch.no_grad():
        expected = part.module(torch.from_numpy(batch).contiguous(memory_format=torch.channels_last)).numpy()
    np.testing.assert_array_equal(part(batch), expected)


def test_a_torso_with_a_hook_or_an_unknown_container_is_called_as_a_module():
    class Twice(nn.Module):  # runs its child twice: its order of layers is not its list of children
        def __init__(self) -> None:
            super().__init__()
            self.inner = nn.Linear(3, 3)

        def forward(self, x):
            return self.inner(self.inner(x))

    torch.manual_seed(0)
    twice = nn.Sequential(nn.Flatten(), Twice())
    part = _TorchPart(twice)
    assert part._chain is None
    x = np.ones((1, 3), np.float32)
    with torch.no_grad():
        np.testing.assert_array_equal(part(x), twice(torch.from_numpy(x)).numpy())
    torso, calls = _cnn_torso(), []
    torso[1].linear[0].register_forward_hook(lambda *args: calls.append(1))
    hooked = _TorchPart(torso)
    assert hooked._chain is None
    hooked(np.zeros((1, 4, 84, 84), np.float32))
    assert calls == [1]
    fast = _TorchPart(_cnn_torso())
    handle = torch.nn.modules.module.register_module_forward_hook(lambda *args: calls.append(2))
    try:
        fast(np.zeros((1, 4, 84, 84), np.float32))  # a global hook, registered after the part was built
    finally:
        handle.remove()
    assert fast._chain is not None and calls.count(2) == 14  # every module's call: 10 layers, 4 containers


@pytest.mark.parametrize("contiguous", [True, False])
def test_repeat_rows_is_broadcast_to_read_only_and_without_a_copy(contiguous):
    base = np.random.default_rng(0).normal(size=(3, 8)).astype(np.float32)
    x = base if contiguous else base[:, ::2]
    rows = repeat_rows(x, 5)
    np.testing.assert_array_equal(rows, np.broadcast_to(x, (5, *x.shape)))
    assert rows.strides[0] == 0 and np.shares_memory(rows, x)
    with pytest.raises(ValueError, match="read-only"):
        rows[0, 0, 0] = 1.0


def test_active_inputs_of_one_observation_follow_the_batch_rule():
    x = np.array([[0.0, 1.5, -0.0, np.nan, 0.0, -2.0]], np.float32)
    general = np.flatnonzero((x != 0).any(axis=0))  # the rule for any batch
    np.testing.assert_array_equal(active_inputs(repeat_rows(x, 4)), general)
    np.testing.assert_array_equal(active_inputs(repeat_rows(x, 4)), [1, 3, 5])
    two = np.vstack([x, [[1.0, 0, 0, 0, 0, 0]]]).astype(np.float32)
    np.testing.assert_array_equal(active_inputs(repeat_rows(two, 4)), [0, 1, 3, 5])


def _deep(method: str, p: float, tanh: bool = False) -> nn.Sequential:
    """A two-hidden-layer MLP sampled at full depth: dropout after each hidden layer, or DropConnect."""
    torch.manual_seed(0)
    mlp = nn.Sequential(nn.Linear(4, 64), nn.ReLU(), nn.Linear(64, 64), nn.ReLU(), nn.Linear(64, 1 if tanh else 2),
                        *([nn.Tanh()] if tanh else []))
    return add_dropout(mlp, p) if method == "dropout" else to_dropconnect(mlp, p)


@pytest.mark.parametrize("p", [0.3, 0.02], ids=["dense-mask", "dropped-positions"])
@pytest.mark.parametrize("method", ["dropout", "dropconnect"])
def test_fixed_masks_are_the_same_sub_networks_at_every_decision(method, p):
    # Sample k is one sub-network: calling twice, or building the estimator again with another
    # sampling seed, gives the same samples; another mask seed gives other ones. One observation at a
    # time gives what the batch gives.
    network = _deep(method, p)
    fixed = MCEstimator(network, n_samples=8, seed=0, masks="fixed")
    first = fixed.estimate(OBS).samples
    np.testing.assert_array_equal(fixed.estimate(OBS).samples, first)
    np.testing.assert_array_equal(MCEstimator(network, n_samples=8, seed=5, masks="fixed").estimate(OBS).samples, first)
    np.testing.assert_allclose(np.concatenate([fixed.estimate(o).samples for o in OBS], axis=1), first, rtol=1e-5, atol=1e-5)
    assert not np.allclose(MCEstimator(network, n_samples=8, masks="fixed", mask_seed=1).estimate(OBS).samples, first)
    assert len({tuple(np.round(s.ravel(), 4)) for s in first}) == 8  # eight different sub-networks


@pytest.mark.parametrize("p", [0.3, 0.02], ids=["dense-mask", "dropped-positions"])
@pytest.mark.parametrize("method", ["dropout", "dropconnect"])
def test_fixed_masks_have_the_sampled_masks_distribution(method, p):
    # Over many sub-networks at one observation, the fixed samples' mean and std are the sampled
    # ones' (4,000 of each: the means within 5 standard errors, the stds within 8%).
    network = _deep(method, p)
    obs = OBS[0]
    fixed = MCEstimator(network, n_samples=4_000, masks="fixed", mask_seed=2).estimate(obs).samples[:, 0]
    sampled = MCEstimator(network, n_samples=4_000, seed=3).estimate(obs).samples[:, 0]
    error = np.sqrt((fixed.var(0) + sampled.var(0)) / 4_000)
    assert np.all(np.abs(fixed.mean(0) - sampled.mean(0)) <= 5 * error + 1e-6)
    np.testing.assert_allclose(fixed.std(0), sampled.std(0), rtol=0.08)


@pytest.mark.parametrize("method", ["dropout", "dropconnect"])
@pytest.mark.parametrize("tanh", [False, True], ids=["dqn", "ddpg"])
def test_fixed_masks_keep_the_sampled_decision(method, tanh):
    # The deployed action is still the mean of freshly sampled masks, drawn from the sampling seed
    # exactly as without fixed masks: the same seed, the same decisions (and so the same episodes).
    network = _deep(method, 0.05, tanh=tanh)
    bounds = {"kind": "actions", "action_low": [-2.0], "action_high": [2.0]} if tanh else {}
    sampled = MCEstimator(network, n_samples=10, seed=4, **bounds)
    fixed = MCEstimator(network, n_samples=10, seed=4, masks="fixed", **bounds)
    for _ in range(3):
        expected, got = sampled.estimate(OBS), fixed.estimate(OBS)
        np.testing.assert_array_equal(got.action, expected.action)
        assert not np.allclose(got.samples, expected.samples)
    if tanh:  # the fixed samples' pre-squash values are what their actions squash
        np.testing.assert_allclose(np.tanh(got.pre_squash) * 2.0, got.samples, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("method", ["dropout", "dropconnect"])
@pytest.mark.parametrize("tanh", [False, True], ids=["dqn", "ddpg"])
def test_fixed_masks_that_decide_decide_by_the_fixed_sub_networks_mean(method, tanh):
    # masks="fixed-decisions": the samples are the K fixed sub-networks' (those of masks="fixed", the
    # same mask seed), and the action is decided by their mean, with no random draw: any sampling
    # seed gives the same actions, and the generator does not move.
    network = _deep(method, 0.05, tanh=tanh)
    bounds = {"kind": "actions", "action_low": [-2.0], "action_high": [2.0]} if tanh else {}
    hybrid = MCEstimator(network, n_samples=10, seed=4, masks="fixed", **bounds)
    deciding = MCEstimator(network, n_samples=10, seed=4, masks="fixed-decisions", **bounds)
    state = deciding.sampling_state
    got, fixed = deciding.estimate(OBS), hybrid.estimate(OBS)
    assert deciding.sampling_state == state
    np.testing.assert_array_equal(got.samples, fixed.samples)
    mean = got.samples.mean(axis=0)
    np.testing.assert_array_equal(got.action, mean if tanh else mean.argmax(axis=1))
    other_seed = MCEstimator(network, n_samples=10, seed=99, masks="fixed-decisions", **bounds).estimate(OBS)
    np.testing.assert_array_equal(other_seed.action, got.action)
    if tanh:  # the sampled decision of masks="fixed" is another one
        assert not np.allclose(fixed.action, got.action)


@pytest.mark.parametrize("masks, draws", [("sampled", True), ("fixed", True), ("fixed-decisions", False)])
def test_an_estimator_says_whether_its_decisions_draw(masks, draws):
    # ``draws``: whether estimating moves the sampling generator on (episodes side by side then draw
    # from streams of their own, oodmon.side_by_side); an ensemble's members draw nothing.
    estimator = MCEstimator(_deep("dropconnect", 0.05), n_samples=10, seed=4, masks=masks)
    state = estimator.sampling_state
    estimator.estimate(OBS)
    assert estimator.draws is draws and (estimator.sampling_state != state) is draws
    ensemble = EnsembleEstimator([_mlp(s) for s in range(3)])
    state = ensemble.sampling_state
    ensemble.estimate(OBS)
    assert not ensemble.draws and ensemble.sampling_state == state


def test_fixed_masks_refuse_what_they_cannot_do():
    with pytest.raises(InvalidParameterError, match="masks='frozen' is not allowed"):
        MCEstimator(_deep("dropout", 0.1), masks="frozen")

    class Wrapped(nn.Module):
        def __init__(self):
            super().__init__()
            self.inner = _deep("dropout", 0.1)

        def forward(self, x):
            return self.inner(x)

    with pytest.raises(ConfigError, match="fixed masks need an nn.Sequential"):
        MCEstimator(Wrapped(), masks="fixed")


@pytest.mark.parametrize("limit", [1 << 30, 0], ids=["masked-matrices", "sparse-dropped"])
@pytest.mark.parametrize("p", [0.3, 0.02], ids=["dense-mask", "dropped-positions"])
def test_a_fixed_dropconnect_layer_computes_its_masked_products(monkeypatch, limit, p):
    # Either way a fixed layer keeps its K masks (the K masked matrices, or the dropped weights as a
    # sparse matrix subtracted from the product with all of them), its rows are the products with
    # the masks drawn as the sampled layer draws them: replayed here from the same generator.
    monkeypatch.setattr(plan, "DENSE_FIXED_LIMIT", limit)
    torch.manual_seed(1)
    layer = DropConnectLinear(6, 5, p=p)
    k = 7
    (op,) = plan.compile_layers([layer])
    fixed = plan.fix_masks([op], k, np.random.default_rng(3))[0]
    assert (fixed.masked is None) == (limit == 0)
    rng = np.random.default_rng(3)
    if p < plan.SPARSE_BELOW:
        mask = np.ones(k * 6 * 5, bool)
        mask[plan.bernoulli_positions(rng, k * 6 * 5, p)] = False
        mask = mask.reshape(k, 6, 5)
    else:
        mask = rng.random((k, 6, 5), dtype=np.float32) >= p
    assert 0 < (~mask).sum() < mask.size
    weight_t = layer.weight.detach().numpy().T / (1 - p)
    bias = layer.bias.detach().numpy()
    inputs = np.random.default_rng(4).normal(size=(3, 6)).astype(np.float32)
    repeated = repeat_rows(inputs, k)  # one batch in every row (the monitor's case), and K batches of their own
    own = np.random.default_rng(5).normal(size=(k, 3, 6)).astype(np.float32)
    own[..., 2] = 0.0  # an input zero in every row: left out of the product with every weight kept
    for x in (repeated, own, repeated[:, :1], own[:, :1]):
        expected = np.einsum("kbi,kio->kbo", x.astype(np.float64), weight_t * mask) + bias
        np.testing.assert_allclose(fixed(x, None), expected, rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match="fixed for 7 rows; got 3"):
        fixed(own[:3], None)


def _sparse_inputs(seed: int, zero_fraction: float) -> np.ndarray:
    """K=20 rows of 400 inputs (K, 1, in), about ``zero_fraction`` of them zero in every row (a ReLU's)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.1, 2.0, size=(20, 1, 400)).astype(np.float32)
    x[..., rng.random(400) < zero_fraction] = 0.0
    return x


def test_sparse_dropconnect_keeps_its_arrays_and_gives_the_samples_of_new_ones():
    # Pendulum's middle layer, 400 -> 300 at p = 0.05: about 60,000 dropped weights per call. Its
    # temporaries go to arrays the layer keeps (grown when a call needs more): the same samples, bit
    # for bit, as with new arrays at every call from the same generator; each call's result a new
    # array (the next call does not write into it); once grown, the arrays are not replaced.
    torch.manual_seed(0)
    (op,) = plan.compile_layers([DropConnectLinear(400, 300, p=0.05)])
    (fresh,) = plan.compile_layers([DropConnectLinear(400, 300, p=0.05)])
    fresh.__dict__.update(op.__dict__ | {"_scratch": plan._fresh})  # the same layer, new arrays at every call
    kept, new = np.random.default_rng(1), np.random.default_rng(1)
    results = []
    for call, zero_fraction in enumerate([0.5, 0.2, 0.8, 0.0, 0.5] * 4):  # active inputs from 80 to 400
        x = _sparse_inputs(call, zero_fraction)
        for inputs in (x, repeat_rows(x[0], 20)):  # K rows of their own, and one batch repeated
            ours = op(inputs, kept)
            assert np.array_equal(ours, fresh(inputs, new))
            results.append((ours, ours.copy()))
    assert all(np.array_equal(result, copy) for result, copy in results)
    arrays = dict(op._scratch._local.__dict__)
    assert {"uniform", "positions", "pair", "slots", "weights", "terms", "wide"} <= set(arrays)
    op(_sparse_inputs(99, 0.5), kept)
    assert all(op._scratch._local.__dict__[name] is array for name, array in arrays.items())


def test_sparse_dropconnect_allocates_no_large_array_per_call():
    # glibc maps fresh pages for each array above 128 KiB and unmaps them when it is freed: ~500 page
    # faults per Pendulum decision when a call made its ~1 MB temporaries anew. Traced by numpy's
    # tracemalloc hooks: a call's peak of new memory stays below half an array of the dropped weights'
    # positions (60,000 int64 here: 480 KB). Measured: 0.14 MB; with the temporaries made anew, 3.1 MB.
    import tracemalloc

    torch.manual_seed(0)
    (op,) = plan.compile_layers([DropConnectLinear(400, 300, p=0.05)])
    rng = np.random.default_rng(0)
    x = _sparse_inputs(0, 0.5)
    for _ in range(5):
        op(x, rng)  # the kept arrays grow to their size
    positions_bytes = 20 * 200 * 300 * 0.05 * 8
    tracemalloc.start()
    try:
        peaks = []
        for _ in range(10):
            tracemalloc.reset_peak()
            before = tracemalloc.get_traced_memory()[0]
            op(x, rng)
            peaks.append(tracemalloc.get_traced_memory()[1] - before)
    finally:
        tracemalloc.stop()
    assert max(peaks) < positions_bytes / 2, peaks


def test_scratch_arrays_grow_per_name_and_thread_and_start_empty_when_copied():
    import copy
    import pickle
    import threading

    scratch = plan.Scratch()
    first = scratch("a", 10, np.int64)
    assert first.shape == (10,) and first.dtype == np.int64
    assert scratch("a", 4, np.int64).base is first.base  # views of one kept array
    grown = scratch("a", 11, np.int64)  # too short: replaced by one twice as long
    assert len(grown) == 11 and len(grown.base) == 20 and grown.base is not first.base
    assert scratch("b", 3, np.float32).dtype == np.float32
    seen = {}
    thread = threading.Thread(target=lambda: seen.setdefault("a", scratch("a", 5, np.int64)))
    thread.start()
    thread.join()
    assert not np.shares_memory(seen["a"], grown)  # another thread, its own arrays
    for twin in (copy.deepcopy(scratch), pickle.loads(pickle.dumps(scratch))):
        assert twin._local.__dict__ == {}
    estimator = MCEstimator(to_dropconnect(_mlp(0), 0.02), seed=0)
    estimator.estimate(OBS[0])
    twin = copy.deepcopy(estimator)
    assert np.array_equal(twin.estimate(OBS[0]).samples, estimator.estimate(OBS[0]).samples)

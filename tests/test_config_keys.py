"""Every setting under `model`, `adversarial` and `sampling` in conf/ reaches the object a run
trains with, and the papers' two main experiments build the protocol's settings (issue 41,
point 2).

Keys are read from the YAML files themselves (conf/model, conf/adversarial, conf/sampling and
the keys those groups get in conf/experiment), so a key added later fails
`test_every_key_of_the_configs_has_a_check` until it gets a check below (or is listed, with
the reason, among the keys that build nothing). A key under a node that Hydra instantiates is
named with the class it configures, e.g. `model.net<ConvSeq2Seq>.C`.

Each check changes one key of a composed config to another valid value, builds the module as
src.train does and looks where the value must show: the network's structure or outputs, what
the optimisers are and their settings, the learning rate over the iterations, and, through a
training iteration, the gradients each optimiser steps with and the eta the network is run
with. A key that is ignored, or read under another name, leaves the object as it was.
"""

from __future__ import annotations

import copy
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import hydra
import pytest
import torch
import torch.nn.functional as F
import yaml
from omegaconf import DictConfig, OmegaConf, open_dict
from torch import nn

from tests import objects
from tests.conftest import CONF

GROUPS = ("model", "adversarial", "sampling")


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    yield from objects.one_thread()


# ------------------------------------------------------------------------------ the keys
def _load(path: Path) -> dict:
    return yaml.safe_load(path.read_text()) or {}


def _is_global(path: Path) -> bool:
    return any(line.strip() == "# @package _global_" for line in path.read_text().splitlines())


def option_node(group: str, option: str) -> dict:
    """What conf/<group>/<option>.yaml puts under `group`."""
    path = CONF / group / f"{option}.yaml"
    data = _load(path)
    if _is_global(path):
        return data.get(group) or {}
    return {k: v for k, v in data.items() if k != "defaults"}


def _chosen(defaults: list, group: str) -> str | None:
    """The option of `group` an `override /group: option` entry of a defaults list names."""
    for entry in reversed(defaults):
        if isinstance(entry, dict):
            for key, value in entry.items():
                if key.split()[-1].strip("/") == group:
                    return value
    return None


def experiment_option(experiment: str, group: str) -> str:
    """The option of `group` an experiment runs with: its own defaults, those of the
    experiments it extends, the model's (a global model file may choose the others), or
    conf/train.yaml's."""

    def own(name: str) -> str | None:
        defaults = _load(CONF / "experiment" / f"{name}.yaml").get("defaults", [])
        for entry in reversed(defaults):
            if isinstance(entry, dict):
                found = _chosen([entry], group)
            else:
                found = None if entry == "_self_" else own(entry)
            if found:
                return found
        return None

    found = own(experiment)
    if found:
        return found
    train_defaults = _load(CONF / "train.yaml")["defaults"]
    plain = {k: v for e in train_defaults if isinstance(e, dict) for k, v in e.items()}
    if group != "model":
        model = experiment_option(experiment, "model")
        model_path = CONF / "model" / f"{model}.yaml"
        found = _chosen(_load(model_path).get("defaults", []), group)
        if found:
            return found
    return plain[group]


def qualified_keys(node: dict, base: dict, prefix: str) -> list[str]:
    """The leaf keys of `node`, each node on the way that Hydra instantiates named with its
    class (`_target_`, from `node` or else from `base`, the option it is merged over)."""

    def name(path: str, here: dict, under: dict) -> str:
        target = here.get("_target_") or (
            under.get("_target_") if isinstance(under, dict) else None
        )
        return f"{path}<{target.rsplit('.', 1)[-1]}>" if isinstance(target, str) else path

    out = []
    for key, value in node.items():
        under = base.get(key, {}) if isinstance(base, dict) else {}
        if isinstance(value, dict) and value:
            out += qualified_keys(value, under, name(f"{prefix}.{key}", value, under))
        else:
            out.append(f"{prefix}.{key}")
    return out


@cache
def config_keys() -> dict[str, list[str]]:
    """Every key under model, adversarial and sampling in conf/ -> the files that set it."""
    found: dict[str, list[str]] = {}

    def add(node: dict, base: dict, group: str, source: str) -> None:
        root = node.get("_target_") or base.get("_target_")
        prefix = f"{group}<{root.rsplit('.', 1)[-1]}>" if isinstance(root, str) else group
        for key in qualified_keys(node, base, prefix):
            found.setdefault(key, []).append(source)

    for group in GROUPS:
        for path in sorted((CONF / group).glob("*.yaml")):
            node = option_node(group, path.stem)
            add(node, node, group, f"conf/{group}/{path.name}")
    for path in sorted((CONF / "experiment").glob("*.yaml")):
        data = _load(path)
        for group in GROUPS:
            if data.get(group):
                base = option_node(group, experiment_option(path.stem, group))
                add(data[group], base, group, f"conf/experiment/{path.name}")
    return found


# Keys that build nothing a run trains with, and why.
BUILDS_NOTHING = {
    "model.name": "names the run (run_name) and the model in tables and folders",
    **{
        f"model.published{where}.{field}": "the published numbers printed beside ours "
        "(src.eval, src.report), not part of the model"
        for where in ("", ".h36m", ".cmu")
        for field in ("paper", "method")
    },
    **{
        f"{node}._target_": "the class Hydra instantiates: another class is another option "
        "of the group, each built by tests/test_config.py (every experiment) and the checks "
        "below (every option)"
        for node in (
            "model.net<ConvSeq2Seq>",
            "model.net<GRUSeq2Seq>",
            "model.net<HisRep>",
            "model.net<ResidualMLP>",
            "model.net<RunningAverage>",
            "model.net<ZeroVelocity>",
            "adversarial.discriminator<Discriminator>",
            "sampling<Constant>",
            "sampling<LinearRamp>",
            "sampling<InverseSigmoid>",
        )
    },
    **{
        f"{node}._partial_": "Hydra's instruction to hand the factory a constructor waiting "
        "for the parameters; false cannot build an optimiser at all"
        for node in ("model.optimizer<Adam>", "model.optimizer<SGD>", "adversarial.optimizer<Adam>")
    },
}


# ------------------------------------------------------------------------------ the bases
DATA = ["data=synthetic", "data.future_len=5", "data.batch_size=2"]
DECAY = ["model.lr_decay_every=2", "model.lr_decay_gamma=0.5"]
TINY_CONV = [
    *DATA,
    "model=conv_s2s",
    "model.net.nf=2",
    "model.net.d_z=8",
    *DECAY,
    "adversarial=li2018",
    "adversarial.discriminator.nf=2",
    "adversarial.discriminator.d_z=8",
    "adversarial.discriminator.d_fc=4",
    "sampling=constant",
]
# The GRU and the MLP with the other groups they choose themselves (no regulariser, eta 1).
TINY_GRU = [*DATA, "model=gru_s2s", "model.net.hidden=8", *DECAY]
TINY_MLP = [*DATA, "model=residual_mlp", "model.net.hidden=8", *DECAY]
TINY_HISREP = [*DATA, "model=hisrep", "model.net.d_model=8", "model.net.num_stage=1", *DECAY]


def with_option(cfg: DictConfig, group: str, option: str) -> DictConfig:
    """`cfg` with another option of a group whose files are not global (what composing with
    `group=option` gives, without composing again)."""
    out = copy.deepcopy(cfg)
    with open_dict(out):
        out[group] = OmegaConf.create(option_node(group, option))
    return out


@pytest.fixture(scope="module")
def bases(tmp_path_factory, synthetic_data_dir) -> dict[str, Any]:
    """The configs each check starts from, and one synthetic datamodule for all of them."""
    out = tmp_path_factory.mktemp("keys")
    conv = objects.compose(TINY_CONV, out / "conv", synthetic_data_dir)
    plain = with_option(conv, "adversarial", "none")
    linear = with_option(plain, "sampling", "linear")
    OmegaConf.update(linear, "sampling.steps", 2)
    return {
        "dm": objects.datamodule(conv.data),
        "conv": conv,
        "conv_plain": plain,
        "conv_linear": linear,
        "conv_sigmoid": with_option(plain, "sampling", "inverse_sigmoid"),
        "running_avg": with_option(conv, "model", "running_avg_2"),
        "gru": objects.compose(TINY_GRU, out / "gru", synthetic_data_dir),
        "mlp": objects.compose(TINY_MLP, out / "mlp", synthetic_data_dir),
        "hisrep": objects.compose(TINY_HISREP, out / "hisrep", synthetic_data_dir),
    }


# ------------------------------------------------------------------------------ what shows
class Built:
    """A module built from a config, and what can be observed of it."""

    def __init__(self, cfg: DictConfig, dm):
        self.cfg, self.dm = cfg, dm
        self.module = objects.module(cfg, dm)
        self.net, self.discriminator = objects.networks(self.module)
        self._trace: objects.Trace | None = None

    def _inputs(self, batch: int = 4):
        g = torch.Generator().manual_seed(1)
        D, T = self.dm.pose_dim, self.dm.future_len
        observed = torch.randn(batch, self.dm.observed_len, D, generator=g)
        future = torch.randn(batch, T, D, generator=g)
        action = torch.arange(batch) % self.dm.num_actions
        return observed, future, action

    def network_behaviour(self) -> tuple:
        """The generator's parameter shapes and its outputs (training mode with a fixed seed and
        the ground truth mixed in at eta 0.5, and evaluation mode)."""
        observed, future, action = self._inputs()
        net, T = self.net, future.shape[1]
        with torch.no_grad():
            torch.manual_seed(2)
            train = net.train()(observed, T, action=action, future=future, eta=0.5)
            evaluated = net.eval()(observed, T, action=action)
        shapes = {k: tuple(v.shape) for k, v in net.state_dict().items()}
        return shapes, train, evaluated

    def discriminator_behaviour(self) -> tuple:
        observed, future, action = self._inputs()
        sequences = torch.cat([observed, future], dim=1)
        disc = self.discriminator
        with torch.no_grad():
            torch.manual_seed(2)
            train = disc.train()(sequences, action)
            evaluated = disc.eval()(sequences, action)
        shapes = {k: tuple(v.shape) for k, v in disc.state_dict().items()}
        return shapes, train, evaluated

    def optimisers(self) -> list[tuple[str, dict]]:
        """(class name, settings) of each optimiser, the generator's first."""
        opts, _ = objects.optimisers(self.module)
        return [
            (type(o).__name__, {k: v for k, v in o.param_groups[0].items() if k != "params"})
            for o in opts
        ]

    def learning_rates(self, iterations: int = 7) -> list[list[float]]:
        """Each optimiser's learning rate at iterations 0..iterations-1."""
        opts, schedulers = objects.optimisers(self.module)
        out = []
        with warnings.catch_warnings():  # the schedulers step without a training step here
            warnings.simplefilter("ignore", UserWarning)
            for _ in range(iterations):
                out.append([o.param_groups[0]["lr"] for o in opts])
                for s in schedulers:
                    s.step()
        return out

    def trace(self, iterations: int = 1) -> objects.Trace:
        """What `iterations` training iterations on one fixed batch step with."""
        if self._trace is None:
            observed, future, action = self._inputs()
            batch = {"observed": observed, "future": future, "action": action}
            self._trace = objects.train_steps(self.module, [batch] * iterations)
        return self._trace


def differs(a: tuple, b: tuple) -> bool:
    """Whether two behaviours (shapes, then tensors) differ anywhere."""
    if a[0] != b[0]:
        return True
    return any(not torch.equal(x, y) for x, y in zip(a[1:], b[1:], strict=True))


def flat_norm(tensors) -> float:
    return float(torch.linalg.vector_norm(torch.cat([t.flatten() for t in tensors])))


# Expectations: (before, after, the new value) -> None, raising when the value does not show.
Expect = Callable[[Built, Built, Any], None]


def network_changes(before: Built, after: Built, value: Any) -> None:
    assert differs(before.network_behaviour(), after.network_behaviour()), "the network is the same"


def kernels_are(value) -> Expect:
    def check(before: Built, after: Built, _value: Any) -> None:
        network_changes(before, after, value)
        kernels = {m.kernel_size for m in after.net.modules() if isinstance(m, nn.Conv2d)}
        assert kernels == {tuple(value)}, kernels

    return check


def discriminator_changes(before: Built, after: Built, value: Any) -> None:
    assert differs(before.discriminator_behaviour(), after.discriminator_behaviour())
    assert not differs(before.network_behaviour(), after.network_behaviour())


def discriminator_kernels(before: Built, after: Built, value: Any) -> None:
    discriminator_changes(before, after, value)
    kernels = {m.kernel_size for m in after.discriminator.modules() if isinstance(m, nn.Conv2d)}
    assert kernels == {tuple(value)}, kernels


def setting_is(which: int, name: str) -> Expect:
    """The generator's (0) or discriminator's (1) optimiser has `name` = the new value; the
    other optimiser keeps its own."""

    def check(before: Built, after: Built, value: Any) -> None:
        new, old = after.optimisers(), before.optimisers()
        assert new[which][1][name] == value, (name, new[which][1][name], value)
        # The other optimiser keeps its own, except that the discriminator's learning rate
        # follows the generator's (conf/adversarial/li2018.yaml).
        if len(new) > 1 and not (which == 0 and name == "lr"):
            assert new[1 - which] == old[1 - which]

    return check


def optimiser_class_is(which: int) -> Expect:
    def check(before: Built, after: Built, value: Any) -> None:
        assert after.optimisers()[which][0] == value.rsplit(".", 1)[-1]

    return check


def learning_rate_decays(before: Built, after: Built, value: Any) -> None:
    """lr x gamma every `lr_decay_every` iterations, for every optimiser (protocol 5, 6.6)."""
    model = after.cfg.model
    every, gamma = model.lr_decay_every, model.lr_decay_gamma
    rates = after.learning_rates()
    for i, at in enumerate(rates):
        expected = [lr * gamma ** (i // every) for lr in rates[0]]
        assert at == pytest.approx(expected), f"iteration {i}: {at} != {expected}"
    assert rates != before.learning_rates()


def optimiser_count(before: Built, after: Built, value: Any) -> None:
    assert len(before.optimisers()) == 2 and len(after.optimisers()) == 1


def l2_reaches(net: str) -> Expect:
    """The step of the generator ('g') or discriminator ('d') gains (new - old) * w on every
    weight tensor and nothing on biases (eq. 9, protocol 6.6); the other step is unchanged."""

    def check(before: Built, after: Built, value: Any) -> None:
        key = "model.lambda_2" if net == "g" else "adversarial.lambda_2"
        delta = value - OmegaConf.select(before.cfg, key)
        (old,), (new,) = before.trace().of(net), after.trace().of(net)
        for name, grad in new.grads.items():
            weight = new.weights[name]
            want = old.grads[name] + (delta * weight if weight.ndim > 1 else 0.0)
            torch.testing.assert_close(grad, want, rtol=1e-4, atol=1e-7, msg=name)
        other = "d" if net == "g" else "g"
        if net == "g":  # the D step comes first: it cannot see the generator's L2 weight
            (o_old,), (o_new,) = before.trace().of(other), after.trace().of(other)
            assert all(torch.equal(o_old.grads[k], o_new.grads[k]) for k in o_old.grads)

    return check


def generator_step_changes(before: Built, after: Built, value: Any) -> None:
    (g_old,), (g_new,) = before.trace().of("g"), after.trace().of("g")
    assert any(not torch.equal(g_old.grads[k], g_new.grads[k]) for k in g_old.grads)
    (d_old,), (d_new,) = before.trace().of("d"), after.trace().of("d")
    assert all(torch.equal(d_old.grads[k], d_new.grads[k]) for k in d_old.grads)


def discriminator_step_changes(before: Built, after: Built, value: Any) -> None:
    (d_old,), (d_new,) = before.trace().of("d"), after.trace().of("d")
    assert any(not torch.equal(d_old.grads[k], d_new.grads[k]) for k in d_old.grads)


def gradient_clipped(before: Built, after: Built, value: Any) -> None:
    (old,), (new,) = before.trace().of("g"), after.trace().of("g")
    assert flat_norm(old.grads.values()) > value, "the check needs a gradient above the clip"
    assert flat_norm(new.grads.values()) == pytest.approx(value, rel=1e-4)


def eta_follows(schedule: Callable[[DictConfig, int], float]) -> Expect:
    def check(before: Built, after: Built, value: Any) -> None:
        trace = after.trace(iterations=2)
        expected = [schedule(after.cfg.sampling, i) for i in range(2)]
        assert trace.etas == pytest.approx(expected), (trace.etas, expected)

    return check


def linear(s: DictConfig, i: int) -> float:
    return s.start + min(i / s.steps, 1.0) * (s.end - s.start)


def inverse_sigmoid(s: DictConfig, i: int) -> float:
    return 1.0 - s.k / (s.k + math.exp(i / s.k))


@dataclass(frozen=True)
class Change:
    base: str  # a config of `bases`
    value: Any  # another valid value of the key
    expect: Expect


CONV = "model.net<ConvSeq2Seq>"
GRU = "model.net<GRUSeq2Seq>"
DISC = "adversarial.discriminator<Discriminator>"
CHANGES: dict[str, Change] = {
    f"{CONV}.C": Change("conv", 10, network_changes),
    f"{CONV}.nf": Change("conv", 3, network_changes),
    f"{CONV}.d_z": Change("conv", 6, network_changes),
    f"{CONV}.kernel": Change("conv", [3, 5], kernels_are([3, 5])),
    f"{CONV}.padding": Change("conv", "valid", network_changes),
    f"{CONV}.long_term": Change("conv", False, network_changes),
    f"{CONV}.dropout": Change("conv", [0.0, 0.0, 0.0], network_changes),
    f"{CONV}.decoder_dropout": Change("conv", 0.0, network_changes),
    f"{CONV}.reference_eta_offset": Change("conv", True, network_changes),
    f"{GRU}.hidden": Change("gru", 6, network_changes),
    f"{GRU}.tied": Change("gru", False, network_changes),
    f"{GRU}.residual": Change("gru", False, network_changes),
    f"{GRU}.one_hot": Change("gru", False, network_changes),
    "model.net<HisRep>.T": Change("hisrep", 12, network_changes),
    "model.net<HisRep>.dct_n": Change("hisrep", 10, network_changes),
    "model.net<HisRep>.d_model": Change("hisrep", 6, network_changes),
    "model.net<HisRep>.num_stage": Change("hisrep", 2, network_changes),
    "model.net<HisRep>.dropout": Change("hisrep", 0.0, network_changes),
    "model.net<ResidualMLP>.C": Change("mlp", 5, network_changes),
    "model.net<ResidualMLP>.hidden": Change("mlp", 6, network_changes),
    "model.net<RunningAverage>.k": Change("running_avg", 4, network_changes),
    "model.optimizer<Adam>.lr": Change("conv", 1e-3, setting_is(0, "lr")),
    "model.optimizer<Adam>.fused": Change("conv", False, setting_is(0, "fused")),
    "model.optimizer<Adam>._target_": Change("conv", "torch.optim.AdamW", optimiser_class_is(0)),
    "model.optimizer<SGD>.lr": Change("gru", 0.01, setting_is(0, "lr")),
    "model.optimizer<SGD>._target_": Change("gru", "torch.optim.Adam", optimiser_class_is(0)),
    "model.lr_decay_every": Change("conv", 3, learning_rate_decays),
    "model.lr_decay_gamma": Change("conv", 0.25, learning_rate_decays),
    "model.lambda_2": Change("conv", 0.5, l2_reaches("g")),
    "model.grad_clip_norm": Change("conv", 1e-3, gradient_clipped),
    "adversarial.enabled": Change("conv", False, optimiser_count),
    "adversarial.lambda_adv": Change("conv", 5.0, generator_step_changes),
    "adversarial.lambda_2": Change("conv", 0.5, l2_reaches("d")),
    "adversarial.reference_fake_slot": Change("conv", True, discriminator_step_changes),
    f"{DISC}.nf": Change("conv", 3, discriminator_changes),
    f"{DISC}.d_z": Change("conv", 6, discriminator_changes),
    f"{DISC}.d_fc": Change("conv", 5, discriminator_changes),
    f"{DISC}.kernel": Change("conv", [3, 5], discriminator_kernels),
    f"{DISC}.padding": Change("conv", "valid", discriminator_changes),
    "adversarial.optimizer<Adam>.lr": Change("conv", 3e-3, setting_is(1, "lr")),
    "adversarial.optimizer<Adam>.fused": Change("conv", False, setting_is(1, "fused")),
    "adversarial.optimizer<Adam>._target_": Change(
        "conv", "torch.optim.AdamW", optimiser_class_is(1)
    ),
    "sampling<Constant>.eta": Change("conv_plain", 0.3, eta_follows(lambda s, i: s.eta)),
    "sampling<LinearRamp>.start": Change("conv_linear", 0.2, eta_follows(linear)),
    "sampling<LinearRamp>.end": Change("conv_linear", 0.6, eta_follows(linear)),
    "sampling<LinearRamp>.steps": Change("conv_linear", 4, eta_follows(linear)),
    "sampling<InverseSigmoid>.k": Change("conv_sigmoid", 2.0, eta_follows(inverse_sigmoid)),
}


def test_every_key_of_the_configs_has_a_check():
    """A key added to conf/ (or one renamed) needs a check here, or a reason in
    BUILDS_NOTHING; and each check names a key that still exists."""
    keys = config_keys()
    unchecked = {k: v for k, v in keys.items() if k not in CHANGES and k not in BUILDS_NOTHING}
    assert not unchecked, "keys without a check (add one to CHANGES): " + "; ".join(
        f"{k} (in {', '.join(sorted(set(v)))})" for k, v in sorted(unchecked.items())
    )
    stale = sorted((set(CHANGES) | set(BUILDS_NOTHING)) - set(keys))
    assert not stale, f"checks of keys that no config has any more: {stale}"


def plain_key(qualified: str) -> str:
    return "".join(part.split("<")[0] for part in qualified.split(">"))


@pytest.mark.parametrize("key", sorted(CHANGES))
def test_changing_a_key_changes_the_built_object_where_it_should(key, bases):
    change = CHANGES[key]
    base = bases[change.base]
    path = plain_key(key)
    old = OmegaConf.select(base, path)
    assert old != change.value, f"{key}: the check must change the value ({old!r})"
    changed = copy.deepcopy(base)
    OmegaConf.update(changed, path, change.value, force_add=False)
    if change.base != "running_avg":  # src.train refuses to train a baseline
        objects.validate(changed)  # another valid value: src.train accepts it
    change.expect(Built(base, bases["dm"]), Built(changed, bases["dm"]), change.value)


# ------------------------------------------------------------------------------ the protocol
def experiment(name: str, tmp_path: Path, data_dir: Path) -> DictConfig:
    return objects.compose([f"experiment={name}"], tmp_path / name, data_dir)


def tiny(cfg: DictConfig, dropout: bool = True) -> DictConfig:
    """`cfg` with small networks (the optimisers, loss weights and schedules do not depend on
    their size), and without dropout when `dropout` is false (so that a gradient can be
    computed again from the weights alone)."""
    out = copy.deepcopy(cfg)
    sizes = {"model.net.nf": 2, "model.net.d_z": 8, "model.net.hidden": 8}
    if out.adversarial.enabled:
        sizes |= {
            f"adversarial.discriminator.{k}": v for k, v in (("nf", 2), ("d_z", 8), ("d_fc", 4))
        }
    if not dropout:
        sizes |= {"model.net.dropout": [0.0, 0.0, 0.0], "model.net.decoder_dropout": 0.0}
        if out.adversarial.enabled:
            sizes["adversarial.discriminator.dropout"] = [0.0, 0.0, 0.0]
    for key, value in sizes.items():
        if OmegaConf.select(out, key) is not None or "dropout" in key:
            OmegaConf.update(out, key, value, force_add=True)
    return out


def protocol_batch(dm, scale: float = 1.0, same_halves: bool = False) -> dict[str, torch.Tensor]:
    """Four windows of random frames (`same_halves`: two windows, each twice, so that both
    draws of an adversarial step are the same windows)."""
    g = torch.Generator().manual_seed(3)
    D, T, n = dm.pose_dim, dm.future_len, 2 if same_halves else 4
    batch = {
        "observed": torch.randn(n, dm.observed_len, D, generator=g),
        "future": scale * torch.randn(n, T, D, generator=g),
        "action": torch.arange(n) % dm.num_actions,
    }
    return {k: torch.cat([v, v]) for k, v in batch.items()} if same_halves else batch


def lr_at(built, iterations: list[int]) -> list[list[float]]:
    """Each optimiser's learning rate at the given iterations (ascending)."""
    opts, schedulers = objects.optimisers(built)
    out, done = [], 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        for it in iterations:
            for _ in range(it - done):
                for s in schedulers:
                    s.step()
            done = it
            out.append([o.param_groups[0]["lr"] for o in opts])
    return out


def set_weights(module: nn.Module, weights: dict[str, torch.Tensor]) -> None:
    with torch.no_grad():
        for name, p in module.named_parameters():
            p.copy_(weights[name])


def gradient(loss: torch.Tensor, module: nn.Module) -> dict[str, torch.Tensor]:
    params = dict(module.named_parameters())
    return dict(zip(params, torch.autograd.grad(loss, list(params.values())), strict=True))


def with_l2(grads: dict[str, torch.Tensor], module: nn.Module, weight: float) -> dict:
    """+ the gradient of weight * sum(w^2) / 2 over weight tensors, biases excluded (TF's
    l2_regularizer, protocol 6.2 and 6.6)."""
    params = dict(module.named_parameters())
    return {
        k: g + (weight * params[k].detach() if params[k].ndim > 1 else 0.0)
        for k, g in grads.items()
    }


def real_label(logit: torch.Tensor, real: bool) -> torch.Tensor:
    """Sigmoid cross-entropy against "real" (1) or "fake" (0), mean over the batch."""
    return F.binary_cross_entropy_with_logits(logit, torch.full_like(logit, float(real)))


def test_li2018_h36m_builds_the_reference_settings(tmp_path, bases, synthetic_data_dir):
    """protocol 6.1-6.6: two Adam (beta1 0.9, beta2 0.999, eps 1e-8, no weight decay) at lr
    5e-5, x0.99 every 10,000 iterations; D steps with eq. (8) + 0.001 * sum w^2/2, G with
    eq. (9): the mean squared error + 0.01 * -log D(fake) + 0.001 * sum w^2/2, no clipping;
    eta 0.95 throughout; C = 20, 2x7 kernels, CEM channels 64/128/128 (discriminator
    128/256/256), codes of 512, decoder 1024 -> 512 -> D, dropout 0.2/0.2/0.5 and 0.5;
    20,000 iterations, batch 16, evaluation every 2,000."""
    dm = bases["dm"]
    cfg = experiment("li2018_h36m", tmp_path, synthetic_data_dir)
    assert (cfg.iterations, cfg.val_every, cfg.data.batch_size) == (20000, 2000, 16)

    full = objects.module(cfg, dm)
    net, disc = objects.networks(full)
    for module in (net, disc):
        kernels = {m.kernel_size for m in module.modules() if isinstance(m, nn.Conv2d)}
        assert kernels == {(2, 7)}
    channels = [m.out_channels for m in net.modules() if isinstance(m, nn.Conv2d)]
    assert channels == [64, 128, 128] * 2
    assert [m.out_channels for m in disc.modules() if isinstance(m, nn.Conv2d)] == [128, 256, 256]
    linears = [(m.in_features, m.out_features) for m in net.modules() if isinstance(m, nn.Linear)]
    assert linears == [(6272, 512), (2688, 512), (1024, 512), (512, dm.pose_dim)]
    drops = [m.p for m in net.modules() if isinstance(m, nn.Dropout)]
    assert drops == [0.2, 0.2, 0.5, 0.2, 0.2, 0.5, 0.5]
    short_inputs = []
    hook = net.short_encoder.register_forward_pre_hook(lambda _m, a: short_inputs.append(a[0]))
    with torch.no_grad():
        net.eval()(torch.zeros(1, dm.observed_len, dm.pose_dim), 1)
    hook.remove()
    assert short_inputs[0].shape[1] == 20  # C

    for which in objects.optimisers(full)[0]:
        assert type(which) is torch.optim.Adam
        group = which.param_groups[0]
        assert group["lr"] == 5e-5 and group["betas"] == (0.9, 0.999) and group["eps"] == 1e-8
        assert group["weight_decay"] == 0 and not group["amsgrad"]
    rates = lr_at(full, [0, 9999, 10000, 19999, 20000])
    decayed = [5e-5, 5e-5, 5e-5 * 0.99, 5e-5 * 0.99, 5e-5 * 0.99**2]
    assert rates == [pytest.approx([r, r]) for r in decayed]
    eta = hydra.utils.instantiate(cfg.sampling)
    assert [eta(i) for i in (0, 10000, 19999)] == [0.95] * 3

    # The losses, from the gradients each optimiser steps with in one iteration (small
    # networks without dropout; both draws the same windows, so whichever the G step takes,
    # it is these; large errors, so that a clip would show).
    small = objects.module(tiny(cfg, dropout=False), dm)
    batch = protocol_batch(dm, scale=30.0, same_halves=True)
    trace = objects.train_steps(small, [batch])
    assert trace.etas == [0.95, 0.95]  # the D step's prediction and the G step's
    (d_step,), (g_step,) = trace.of("d"), trace.of("g")
    net, disc = objects.networks(small)
    stepped_d = {k: p.detach().clone() for k, p in disc.named_parameters()}
    half = {k: v[:2] for k, v in batch.items()}
    observed, future, action = half["observed"], half["future"], half["action"]
    T = future.shape[1]

    set_weights(net, g_step.weights)  # the generator has not stepped yet at the D step
    set_weights(disc, d_step.weights)
    with torch.no_grad():
        fake = net.train()(observed, T, action=action, future=future, eta=0.95)
    real_seq, fake_seq = torch.cat([observed, future], 1), torch.cat([observed, fake], 1)
    eq8 = real_label(disc.train()(real_seq, action), True)
    eq8 = eq8 + real_label(disc(fake_seq, action), False)
    want_d = with_l2(gradient(eq8, disc), disc, 1e-3)
    for name, g in d_step.grads.items():
        torch.testing.assert_close(g, want_d[name], rtol=1e-4, atol=1e-7, msg=f"D {name}")

    set_weights(disc, stepped_d)  # the discriminator as the G step sees it: after its step
    prediction = net(observed, T, action=action, future=future, eta=0.95)
    eq7 = F.mse_loss(prediction, future)  # mean over batch x frames x dimensions
    eq9 = eq7 + 0.01 * real_label(disc(torch.cat([observed, prediction], 1), action), True)
    want_g = with_l2(gradient(eq9, net), net, 1e-3)
    assert flat_norm(want_g.values()) > 10.0, "the check needs a gradient a clip would bend"
    for name, g in g_step.grads.items():
        torch.testing.assert_close(g, want_g[name], rtol=1e-4, atol=1e-7, msg=f"G {name}")


def test_martinez2017_res_sup_builds_the_reference_settings(tmp_path, bases, synthetic_data_dir):
    """protocol 5: plain SGD at lr 0.005 (no momentum, no weight decay) x0.95 every 10,000
    iterations; the loss is the mean squared error alone (no L2, no adversarial term) with
    the gradient clipped to global norm 5; the decoder is fed its own predictions (eta 1);
    one tied GRU of 1024 units with the action one-hot (input 54 + 15 on H3.6M); 100,000
    iterations, batch 16, evaluation every 1,000."""
    dm = bases["dm"]
    cfg = experiment("martinez2017_res_sup", tmp_path, synthetic_data_dir)
    assert (cfg.iterations, cfg.val_every, cfg.data.batch_size) == (100000, 1000, 16)

    full = objects.module(cfg, dm)
    net, disc = objects.networks(full)
    assert disc is None
    inputs = dm.pose_dim + dm.num_actions  # one-hot
    gru = 3 * 1024 * (inputs + 1024) + 6 * 1024  # nn.GRUCell's weights and biases
    assert sum(p.numel() for p in net.parameters()) == gru + 1024 * inputs + inputs  # tied
    (opt,) = objects.optimisers(full)[0]
    assert type(opt) is torch.optim.SGD
    group = opt.param_groups[0]
    assert group["lr"] == 0.005 and group["momentum"] == 0 and group["weight_decay"] == 0
    assert group["dampening"] == 0 and not group["nesterov"]
    rates = lr_at(full, [0, 9999, 10000, 20000])
    assert rates == [pytest.approx([r]) for r in [0.005, 0.005, 0.005 * 0.95, 0.005 * 0.95**2]]

    small = objects.module(tiny(cfg), dm)
    batch = protocol_batch(dm, scale=30.0)  # a gradient well above the clip norm
    trace = objects.train_steps(small, [batch, batch])
    assert trace.etas == [1.0, 1.0]
    first = trace.of("g")[0]
    net = objects.networks(small)[0]
    set_weights(net, first.weights)
    params = dict(net.named_parameters())
    T = batch["future"].shape[1]
    prediction = net.train()(batch["observed"], T, action=batch["action"], future=batch["future"])
    loss = F.mse_loss(prediction, batch["future"])
    raw = torch.autograd.grad(loss, list(params.values()))
    norm = flat_norm(raw)
    assert norm > 5.0, "the check needs a gradient above the clip norm"
    for name, g in zip(params, raw, strict=True):
        torch.testing.assert_close(first.grads[name], g * 5.0 / (norm + 1e-6), rtol=1e-4, atol=1e-8)


def test_mao2020_h36m_builds_the_authors_settings(tmp_path, synthetic_data_dir):
    """shared docs/hisrep.md §0, §1, §6: S1, S6-S9 with the root zeroed and raw radians, windows
    of 50 + 10 frames, batch 32; Adam 5e-4 x 0.1^(1/50) before every epoch of 4,468
    iterations, 16 epochs; the published network (3,076,904 parameters on the 48 dims); the
    generator steps with the gradient of the authors' L1 objective, not of eq. (7)."""
    cfg = experiment("mao2020_h36m", tmp_path, synthetic_data_dir)
    assert (cfg.iterations, cfg.val_every, cfg.data.batch_size) == (16 * 4468, 4468, 32)
    assert list(cfg.data.train_subjects) == [1, 6, 7, 8, 9] and not cfg.adversarial.enabled
    assert (cfg.data.val_subject, cfg.data.val_stride) == (11, 10)  # selected on S11
    data = {k: cfg.data[k] for k in ("zero_root", "normalize", "train_future_len")}
    assert data == {"zero_root": True, "normalize": False, "train_future_len": 10}
    # model=hisrep brings these data settings to any dataset: here the synthetic one.
    dm = objects.datamodule(
        objects.compose(["data=synthetic", "model=hisrep"], tmp_path / "s", synthetic_data_dir).data
    )
    assert dm.pose_dim == 48
    full = objects.module(cfg, dm)
    net = objects.networks(full)[0]
    assert sum(p.numel() for p in net.parameters()) == 3_076_904
    (opt,) = objects.optimisers(full)[0]
    assert type(opt) is torch.optim.Adam and opt.param_groups[0]["weight_decay"] == 0
    epoch = 4468
    rates = lr_at(full, [0, epoch - 1, epoch, 15 * epoch])
    want = [5e-4 * 0.1 ** (e / 50) for e in (1, 1, 2, 16)]  # epoch 1 already decayed once
    assert rates == [pytest.approx([r], rel=1e-5) for r in want]

    small = objects.module(OmegaConf.merge(cfg, {"model": {"net": {
        "d_model": 8, "num_stage": 1, "dropout": 0.0}}}), dm)  # fmt: skip
    batch = next(iter(dm.train_dataloader()))
    assert batch["future"].shape[1] == 10
    (step,) = objects.train_steps(small, [batch]).of("g")
    net = objects.networks(small)[0]
    set_weights(net, step.weights)
    want = gradient(net.train().objective(batch["observed"], batch["future"]), net)
    for name, g in step.grads.items():
        torch.testing.assert_close(g, want[name], rtol=1e-4, atol=1e-7, msg=name)

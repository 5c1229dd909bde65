"""The paper's agent: BoTorch GP surrogate + probability of improvement with kappa (eq. 23).

A ``SingleTaskGP`` (Matern/RBF default kernel of BoTorch, learned noise) on xi scaled to the
unit cube with ``Normalize`` inputs and ``Standardize`` outcomes models the cost J(xi); the next
xi maximizes PI(xi) = Phi((J_ref - kappa - mu(xi)) / sigma(xi)) (or its log, ``LogPI``) with
``optimize_acqf``. The first ``n_init`` points are a scrambled Sobol design (Algorithm 1, line 8).

Speed: the GP hyperparameters are warm-started from the previous fit and
refitted only every ``refit_every`` evaluations (in between the GP is only conditioned on the new
data), and ``optimize_acqf`` uses 2 L-BFGS-B restarts from 256 raw samples (enough for a 3-D
box) and does not retry a start that ends with a warning (the best point found is kept). All
randomness (Sobol scrambling, restarts, the fit's retries) comes from the agent's seed, inside
``torch.random.fork_rng`` so the caller's global torch state is untouched.
"""

from __future__ import annotations

import numpy as np
import torch
from botorch.acquisition.analytic import LogProbabilityOfImprovement, ProbabilityOfImprovement
from botorch.acquisition.monte_carlo import qProbabilityOfImprovement
from botorch.acquisition.objective import GenericMCObjective
from botorch.fit import fit_gpytorch_mll
from botorch.models import ModelListGP, SingleTaskGP
from botorch.models.transforms import Normalize, Standardize
from botorch.optim import optimize_acqf
from botorch.sampling import SobolQMCNormalSampler
from gpytorch.mlls import ExactMarginalLogLikelihood

from inertia_gym.agents.base import AskTellAgent, candidates
from inertia_gym.errors import ConfigError

ACQUISITIONS = ("pi", "logpi")
INCUMBENTS = ("observed", "posterior")
# State-dict entries that are hyperparameters (warm-started), not data-dependent buffers.
_HYPER_PREFIXES = ("likelihood.", "mean_module.", "covar_module.")
_UNIT = torch.tensor([[0.0] * 3, [1.0] * 3], dtype=torch.double)
#: Width of the smooth step of the constrained PI, relative to the scale of its argument: the
#: improvement in standard deviations of the costs, the constraint in fractions of the budget.
#: A hundredth keeps the step sharp against the GPs' own spread while giving it gradients.
CONSTRAINT_SMOOTHING = 0.01
#: Monte Carlo samples of the constrained PI (quasi-random, seeded): its estimate's error,
#: about 1/256 of a probability, is far below the differences the optimiser ranks.
CONSTRAINED_SAMPLES = 256


def fit_gp(x: torch.Tensor, y: torch.Tensor, hyper: dict | None = None,
           refit: bool = True) -> SingleTaskGP:
    """Build a GP on x (n, 3) in the unit cube and costs y (n, 1), in eval mode.

    Hyperparameters come from `hyper` (a state-dict subset) if given, then a maximum-likelihood
    refit (starting from them) if `refit`.
    """
    model = SingleTaskGP(x, y, input_transform=Normalize(d=x.shape[-1], bounds=_UNIT),
                         outcome_transform=Standardize(m=1))
    if hyper is not None:
        model.load_state_dict(hyper, strict=False)
    if refit:
        fit_gpytorch_mll(ExactMarginalLogLikelihood(model.likelihood, model))
    return model.eval()


def hyperparameters(model: SingleTaskGP) -> dict:
    """Return the warm-startable part of a GP's state dict (kernel, mean, noise)."""
    return {k: v.detach().clone() for k, v in model.state_dict().items()
            if k.startswith(_HYPER_PREFIXES)}


def posterior_best(actions, costs, seed: int = 0, within=None) -> tuple[int, float]:
    """Return (index, posterior mean cost) of the evaluated action with the lowest GP mean.

    actions (n, 3) in [-1, 1], costs (n,), n >= 2. A recommendation that does not chase one lucky
    noisy evaluation: a GP like BO's surrogate (fitted afresh, seeded) smooths the costs, and the
    evaluated point it predicts cheapest is returned with that prediction (in the costs' units).
    It depends only on the history, so it scores any agent's evaluations the same way.
    within (n,) bool, optional: pick among these evaluations only, when there are any (the GP
    still learns from all).
    """
    actions = np.asarray(actions, dtype=float)
    x = torch.tensor((actions + 1.0) / 2.0, dtype=torch.double)
    y = torch.tensor(np.asarray(costs, dtype=float)[:, None], dtype=torch.double)
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        model = fit_gp(x, y)
        with torch.no_grad():
            mean = model.posterior(x).mean.squeeze(-1).numpy()
    pool = candidates(within, len(mean))
    best = int(pool[np.argmin(mean[pool])])
    return best, float(mean[best])


class BOAgent(AskTellAgent):
    """Bayesian optimisation of xi with a GP and (Log)PI, eq. (23).

    n_init : Sobol points before the first GP (>= 2).
    kappa : the exploration margin of eq. (23), in units of the standard deviation of the costs
        observed so far (scale-free, so one default serves both costs and any spacecraft).
    acquisition : "pi" (eq. 23) or "logpi" (its logarithm; same argmax, better gradients where
        PI underflows).
    incumbent : J_ref of eq. (23): "observed" is the lowest cost seen (the paper); "posterior" is
        the lowest GP posterior mean over the evaluated points (robust to a lucky noisy draw).
    refit_every : refit hyperparameters every this many evaluations (1 = every iteration).
    num_restarts, raw_samples, maxiter : ``optimize_acqf`` settings.
    Fitted attributes: ``x_`` (n, 3) unit-cube inputs, ``y_`` (n,) costs, ``model_``.

    **Under an impulse budget** (a step's info names one) the budget is a constraint, not a
    cost: a second GP models g(xi) = impulse_demand / impulse_budget - 1, the share by which
    the bursts the law asks for overdraw the budget (g <= 0: they fire as designed), and the
    next xi maximises PI times the probability that g <= 0 (BoTorch's
    ``qProbabilityOfImprovement`` with ``constraints``, on a ``ModelListGP`` of the two). The
    incumbent is the best evaluation within the budget; before there is one, the acquisition
    is the probability of being within it (``acquisition`` chooses the unconstrained form
    only). Fitted attribute ``g_`` (n,).
    """

    name = "bo"

    def __init__(self, seed: int, *, n_init: int = 8, kappa: float = 0.01,
                 acquisition: str = "logpi", incumbent: str = "observed", refit_every: int = 10,
                 num_restarts: int = 2, raw_samples: int = 256, maxiter: int = 30):
        super().__init__(seed)
        if acquisition not in ACQUISITIONS:
            raise ConfigError(f"acquisition must be one of {ACQUISITIONS}, got {acquisition!r}")
        if incumbent not in INCUMBENTS:
            raise ConfigError(f"incumbent must be one of {INCUMBENTS}, got {incumbent!r}")
        if n_init < 2 or refit_every < 1 or kappa < 0:
            raise ConfigError(f"need n_init >= 2, refit_every >= 1, kappa >= 0; got {n_init}, "
                              f"{refit_every}, {kappa}")
        self.n_init, self.kappa, self.acquisition = int(n_init), float(kappa), acquisition
        self.incumbent, self.refit_every = incumbent, int(refit_every)
        self.num_restarts, self.raw_samples, self.maxiter = num_restarts, raw_samples, maxiter
        engine = torch.quasirandom.SobolEngine(3, scramble=True, seed=self.seed)
        self._design = engine.draw(self.n_init, dtype=torch.double).numpy()
        self.x_: list[np.ndarray] = []
        self.y_: list[float] = []
        self.model_: SingleTaskGP | None = None
        self._hyper: dict | None = None
        self.g_: list[float] = []
        self._g_hyper: dict | None = None

    def ask(self) -> np.ndarray:
        """Sobol point while n < n_init, else the maximiser of the acquisition."""
        n = len(self.x_)
        if n < self.n_init:
            return 2.0 * self._design[n] - 1.0
        x = torch.tensor(np.array(self.x_), dtype=torch.double)
        y = torch.tensor(np.array(self.y_)[:, None], dtype=torch.double)
        refit = self._hyper is None or (n - self.n_init) % self.refit_every == 0
        with torch.random.fork_rng():
            torch.manual_seed(self.seed * 100_003 + n)
            self.model_ = fit_gp(x, y, self._hyper, refit=refit)
            if refit:
                self._hyper = hyperparameters(self.model_)
            if self.incumbent == "observed":
                ref = float(y.min())
            else:
                with torch.no_grad():
                    ref = float(self.model_.posterior(x).mean.min())
            best_f = ref - self.kappa * float(y.std())
            if self.g_:
                if len(self.g_) != n:
                    raise ConfigError(f"under a budget, observe() each step's info before tell(): "
                                      f"{len(self.g_)} observed for {n} told")
                acq = self._constrained_acquisition(x, y, refit, n)
            else:
                acq_cls = ProbabilityOfImprovement if self.acquisition == "pi" else \
                    LogProbabilityOfImprovement
                acq = acq_cls(self.model_, best_f=best_f, maximize=False)
            cand, _ = optimize_acqf(acq, bounds=_UNIT, q=1, num_restarts=self.num_restarts,
                                    raw_samples=self.raw_samples,
                                    options={"seed": self.seed * 100_003 + n,
                                             "maxiter": self.maxiter},
                                    retry_on_optimization_warning=False)
        return 2.0 * cand.detach().numpy().reshape(3) - 1.0

    def _constrained_acquisition(self, x, y, refit: bool, n: int) -> qProbabilityOfImprovement:
        """PI of the cost times the probability of staying within the budget (class docstring)."""
        g = torch.tensor(np.array(self.g_)[:, None], dtype=torch.double)
        g_model = fit_gp(x, g, self._g_hyper, refit=refit)
        if refit:
            self._g_hyper = hyperparameters(g_model)
        within = g.squeeze(-1) <= 0.0
        spread = max(float(y.std()), 1e-12)
        if within.any():
            if self.incumbent == "observed":
                ref = float(y.squeeze(-1)[within].min())
            else:
                with torch.no_grad():
                    ref = float(self.model_.posterior(x[within]).mean.min())
            best_f = -(ref - self.kappa * spread)
        else:  # nothing within the budget yet: every xi improves, only feasibility counts
            best_f = -(float(y.max()) + 1e3 * spread)
        return qProbabilityOfImprovement(
            ModelListGP(self.model_, g_model), best_f=best_f,
            sampler=SobolQMCNormalSampler(torch.Size([CONSTRAINED_SAMPLES]), seed=self.seed * 100_003 + n),
            objective=GenericMCObjective(lambda z, X=None: -z[..., 0]),
            constraints=[lambda z: z[..., 1]], tau=CONSTRAINT_SMOOTHING * spread,
            eta=CONSTRAINT_SMOOTHING)

    def observe(self, action: np.ndarray, info: dict) -> None:
        """Record g = impulse_demand / impulse_budget - 1 when the step ran under a budget."""
        budget = info.get("impulse_budget")
        if budget is not None:
            self.g_.append(float(info["impulse_demand"]) / float(budget) - 1.0)

    def tell(self, action: np.ndarray, cost: float) -> None:
        """Add (action, cost) to the data set D_i."""
        self.x_.append((np.asarray(action, dtype=float) + 1.0) / 2.0)
        self.y_.append(float(cost))

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
from botorch.fit import fit_gpytorch_mll
from botorch.models import SingleTaskGP
from botorch.models.transforms import Normalize, Standardize
from botorch.optim import optimize_acqf
from gpytorch.mlls import ExactMarginalLogLikelihood

from inertia_gym.agents.base import AskTellAgent
from inertia_gym.errors import ConfigError

ACQUISITIONS = ("pi", "logpi")
INCUMBENTS = ("observed", "posterior")
# State-dict entries that are hyperparameters (warm-started), not data-dependent buffers.
_HYPER_PREFIXES = ("likelihood.", "mean_module.", "covar_module.")
_UNIT = torch.tensor([[0.0] * 3, [1.0] * 3], dtype=torch.double)


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


def posterior_best(actions, costs, seed: int = 0) -> tuple[int, float]:
    """Return (index, posterior mean cost) of the evaluated action with the lowest GP mean.

    actions (n, 3) in [-1, 1], costs (n,), n >= 2. A recommendation that does not chase one lucky
    noisy evaluation: a GP like BO's surrogate (fitted afresh, seeded) smooths the costs, and the
    evaluated point it predicts cheapest is returned with that prediction (in the costs' units).
    It depends only on the history, so it scores any agent's evaluations the same way.
    """
    actions = np.asarray(actions, dtype=float)
    x = torch.tensor((actions + 1.0) / 2.0, dtype=torch.double)
    y = torch.tensor(np.asarray(costs, dtype=float)[:, None], dtype=torch.double)
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        model = fit_gp(x, y)
        with torch.no_grad():
            mean = model.posterior(x).mean.squeeze(-1).numpy()
    best = int(np.argmin(mean))
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
            acq_cls = ProbabilityOfImprovement if self.acquisition == "pi" else \
                LogProbabilityOfImprovement
            acq = acq_cls(self.model_, best_f=best_f, maximize=False)
            cand, _ = optimize_acqf(acq, bounds=_UNIT, q=1, num_restarts=self.num_restarts,
                                    raw_samples=self.raw_samples,
                                    options={"seed": self.seed * 100_003 + n,
                                             "maxiter": self.maxiter},
                                    retry_on_optimization_warning=False)
        return 2.0 * cand.detach().numpy().reshape(3) - 1.0

    def tell(self, action: np.ndarray, cost: float) -> None:
        """Add (action, cost) to the data set D_i."""
        self.x_.append((np.asarray(action, dtype=float) + 1.0) / 2.0)
        self.y_.append(float(cost))

"""mcpilco/CartpoleSwingUp-v0 against independent physics and the task definition."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from mcpilco.envs.cartpole import CARTPOLE_TASK, CartpoleSwingUpEnv

M_CART, M_POLE, L, B, G = 0.5, 0.5, 0.5, 0.1, 9.81


def cartpole_ode(_t, s, force):
    """Cart-pole with a uniform rod from Lagrange's equations (theta = 0 down, tip at
    x + L sin(theta)):

        (M + m) xdd + m L/2 cos(th) thdd = f - b xd + m L/2 sin(th) thd^2
        m L/2 cos(th) xdd + m L^2/3 thdd = -m g L/2 sin(th)
    """
    x, xd, th, thd = s
    h = M_POLE * L / 2
    mass = np.array([[M_CART + M_POLE, h * np.cos(th)], [h * np.cos(th), M_POLE * L**2 / 3]])
    rhs = np.array([force - B * xd + h * np.sin(th) * thd**2, -h * G * np.sin(th)])
    xdd, thdd = np.linalg.solve(mass, rhs)
    return [xd, xdd, thd, thdd]


@pytest.fixture
def env():
    e = CartpoleSwingUpEnv(obs_noise_std=0.0)
    e.reset(seed=0)
    yield e
    e.close()


def test_model_parameters(env):
    m, d = env.model, env.data
    assert m.opt.timestep == 0.005 and env.frame_skip == 10 and env.dt == pytest.approx(0.05)
    assert m.opt.gravity[2] == -9.81
    assert m.body("cart").mass[0] == 0.5 and m.body("pole").mass[0] == 0.5
    np.testing.assert_array_equal(m.dof_armature, 0.0)
    assert m.joint("slider").damping[0] == 0.1 and m.joint("hinge").damping[0] == 0.0
    # joint-space inertia vs. analytic [[M+m, m L/2 cos], [m L/2 cos, m L^2/3]]
    import mujoco

    for theta in (0.0, 1.0, np.pi):
        env.set_cartpole_state([0.3, 0.0, theta, 0.0])
        full = np.zeros((2, 2))
        mujoco.mj_fullM(m, d, full)
        h = M_POLE * L / 2 * np.cos(theta)
        np.testing.assert_allclose(
            full, [[M_CART + M_POLE, h], [h, M_POLE * L**2 / 3]], rtol=1e-9, atol=1e-12
        )


@pytest.mark.parametrize(
    "s0, action",
    [([0.0, 0.0, 0.0, 0.0], 0.7), ([0.1, -0.5, 2.0, 3.0], -0.4), ([0.0, 0.2, np.pi - 0.3, 0], 0)],
)
def test_trajectory_matches_equations_of_motion(env, s0, action):
    """10 steps (0.5 s) of constant force against solve_ivp of the cart-pole ODE."""
    env.set_cartpole_state(s0)
    t_eval = env.dt * np.arange(1, 11)
    ref = solve_ivp(
        cartpole_ode, (0, 0.5), s0, args=(10.0 * action,), t_eval=t_eval, rtol=1e-10, atol=1e-12
    ).y.T
    sim = np.array([env.step(np.array([action]))[4]["state"] for _ in range(10)])
    np.testing.assert_allclose(sim, ref, atol=1e-5)  # RK4 at 0.005 s is far more accurate


def test_force_is_clipped_to_10_newton(env):
    s0 = [0.0, 0.0, 0.5, 0.0]
    env.set_cartpole_state(s0)
    big = env.step(np.array([7.0]))[4]["state"]
    env.set_cartpole_state(s0)
    one = env.step(np.array([1.0]))[4]["state"]
    np.testing.assert_array_equal(big, one)


def test_theta_sign_and_geometry(env):
    """Positive theta puts the pole (centre at L/2) towards +x; theta = 0 hangs down."""
    for theta in (0.0, 0.4, np.pi, -2.0):
        env.set_cartpole_state([0.2, 0.0, theta, 0.0])
        centre = env.data.geom("pole").xpos
        np.testing.assert_allclose(
            [centre[0], centre[2]],
            [0.2 + L / 2 * np.sin(theta), -L / 2 * np.cos(theta)],
            atol=1e-12,
        )


def test_theta_is_not_wrapped(env):
    env.set_cartpole_state([0.0, 0.0, 3 * np.pi - 0.1, 0.0])
    obs, *_ = env.step(np.array([0.0]))
    assert obs[2] > 2 * np.pi


def test_reset_distribution_and_observation_noise():
    env = CartpoleSwingUpEnv(obs_noise_std=0.05)
    states, noise = [], []
    for seed in range(300):
        obs, info = env.reset(seed=seed)
        states.append(info["state"])
        noise.append(obs - info["state"])
    states, noise = np.array(states), np.array(noise)
    # s0 ~ N(0, 0.01^2 I): with 300 draws the sample std is within ~15% of the truth
    np.testing.assert_allclose(states.std(axis=0), 0.01, rtol=0.2)
    np.testing.assert_allclose(states.mean(axis=0), 0.0, atol=0.003)
    np.testing.assert_allclose(noise.std(axis=0), 0.05, rtol=0.2)
    assert obs.dtype == np.float64 and obs.shape == (4,)


def test_upright_hold_is_a_success_and_cost_zero(env):
    env.set_cartpole_state([0.0, 0.0, np.pi, 0.0])  # unstable equilibrium, held exactly
    for t in range(1, CARTPOLE_TASK["horizon"] + 1):
        obs, reward, terminated, truncated, info = env.step(np.array([0.0]))
        assert info["upright"] and not terminated
        assert truncated == (t == 60)
    assert info["success"] is True
    assert reward == pytest.approx(0.0, abs=1e-9) and info["cost"] == -reward


def test_upright_but_cart_far_is_not_a_success(env):
    env.set_cartpole_state([0.6, 0.0, np.pi, 0.0])
    for _ in range(60):
        info = env.step(np.array([0.0]))[4]
    assert info["upright"] and info["success"] is False


def test_episode_length_argument():
    env = CartpoleSwingUpEnv(episode_steps=5, obs_noise_std=0.0)
    env.reset(seed=1)
    flags = [env.step(np.array([0.0]))[3] for _ in range(5)]
    assert flags == [False] * 4 + [True]


def test_reward_is_minus_cost_of_true_state(env):
    obs, reward, *_, info = env.step(np.array([0.3]))
    x, theta = info["state"][0], info["state"][2]
    expected = 1 - np.exp(
        -((abs(np.arctan2(np.sin(theta), np.cos(theta))) - np.pi) ** 2) - x**2 / 2.25
    )
    assert info["cost"] == pytest.approx(expected) and reward == -info["cost"]


def test_bad_constructor_arguments():
    with pytest.raises(ValueError, match="obs_noise_std"):
        CartpoleSwingUpEnv(obs_noise_std=-1.0)
    with pytest.raises(ValueError, match="episode_steps"):
        CartpoleSwingUpEnv(episode_steps=0)
    with pytest.raises(ValueError, match="l_theta"):
        CartpoleSwingUpEnv(l_theta=0.0)

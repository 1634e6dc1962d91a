"""The rollout summary's pose validity, told apart from the arm hiding the object (issue 35,
item 7): ``ScorbotGraspEnv.object_visibility`` (ground truth, for scoring) and the summary's
share of valid estimates made with a clear view."""


def test_rollout_summary_says_what_the_valid_share_measures_and_the_clear_view_share():
    """Valid estimates over all steps fall while the arm hides the object; the share over the
    estimates made while nothing hid it (ground truth, for the summary only) tells the
    estimator from the arm's path."""
    from scorbot_gym import make_env
    from scorbot_gym.evaluation import format_summary, run_episodes
    from scorbot_gym.evaluation.summary import summarize
    from scorbot_gym.policies import ScriptedGraspPolicy

    env = make_env(
        "ScorbotGrasp-v0", pose="noisy_oracle", pose_kwargs={"dropout": 0.5}, objects=["box"],
        cameras=["top"], image_width=64, image_height=48,
    )  # fmt: skip
    try:
        base = env.unwrapped
        env.reset(seed=3)
        assert base.object_visibility("top") == 1.0  # the arm at home
        results = run_episodes(env, ScriptedGraspPolicy.for_env(env), 2, 3, progress=False)
    finally:
        env.close()
    p = summarize(results)["perception"]
    assert 0 < p["clear_view_estimates"] < p["estimates"]  # the arm hid the box for a while
    assert 0 < p["clear_view_valid_rate"] < 1  # dropout: valid or not, whatever the view
    text = " ".join(format_summary(summarize(results)).split())  # without the column padding
    assert f"of {p['estimates']} estimates, one per estimating step" in text
    assert "the arm hides the object" in text
    n = p["clear_view_estimates"]
    assert f"with a clear view {p['clear_view_valid_rate']:.1%} of the {n} estimates" in text


def test_visibility_drops_where_the_arm_covers_the_object_in_the_image():
    """The rays' verdict agrees with the rendered mask: the object's visible pixels shrink
    where its visibility does."""
    from scorbot_gym import make_env
    from scorbot_gym.policies import ScriptedGraspPolicy

    env = make_env("ScorbotGrasp-v0", pose="oracle", objects=["box"], cameras=["top"],
                   image_width=64, image_height=48)  # fmt: skip
    try:
        base = env.unwrapped
        obs, info = env.reset(seed=3)
        policy = ScriptedGraspPolicy.for_env(env)
        policy.reset(obs, info)
        seen = []
        for _ in range(40):
            obs, *_, info = env.step(policy.act(obs))
            mask = base.sim.render("top", "segmentation", 160, 120)  # a test may look inside
            seen.append((base.object_visibility("top"), int(mask.sum())))
    finally:
        env.close()
    clear = [px for v, px in seen if v == 1.0]
    hidden = [px for v, px in seen if v <= 0.5]
    assert clear and hidden and max(hidden) < 0.8 * min(clear)

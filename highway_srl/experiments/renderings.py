"""Single episodes for people to look at: renderings and the demo summary."""

from __future__ import annotations

from pathlib import Path


from highway_srl.agents.checkpoint import naming, publish, temp_beside
from highway_srl.constants import DEFAULT_ADVERSARY
from highway_srl.sim import World
from highway_srl.sim.ego_driver import idm_ego
from highway_srl.sim.render import capture, save_gif, save_png

POLICIES = ("idm",)


def drawn(path: Path, draw, overwrite: bool = True) -> Path:
    """path written by draw(temporary path) and then moved into place in one step (checkpoint.publish): a
    full disk or an interrupt leaves the file that was there, never a truncated one."""
    tmp = temp_beside(path)
    try:
        with naming(path):
            draw(tmp)
        publish(tmp, path, overwrite)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _policy_driver(policy: str):
    if policy not in POLICIES:
        raise ValueError(f"unknown policy {policy!r}; choose one of {', '.join(POLICIES)} or give a trained run folder")
    return lambda world: (idm_ego(world), [])


def render_episode(run, scenario, traffic, adversarial, policy, seed, out: Path, steps: int = 320, backend: str = "ours",
                   progress: bool = False, profile: str | None = None, adversary: str | None = None,
                   overwrite: bool = True):
    """Drive one episode and write `out` (GIF) and a PNG of its middle frame beside it, each drawn into a
    temporary file and then moved into place (overwrite False: never over a file that exists).

    progress: a bar over the steps driven, then the frames drawn. profile, adversary: None = the run's own
    (without a run: the paper's adversary)."""
    if out.suffix.lower() != ".gif":
        raise ValueError(f"--out must end in .gif, got {str(out)!r}")
    if run is not None:
        from highway_srl.experiments.policy import load_driver
        from highway_srl.experiments.runs import train_config

        driver, scenario = load_driver(run, scenario, profile)
        adversary = adversary or train_config(run).adversary
    else:
        driver = _policy_driver(policy)
        scenario = scenario or "two-lane"
    if backend == "ours":
        world = World(scenario, traffic, adversarial=adversarial, num_envs=1, seed=seed, adversary=adversary or DEFAULT_ADVERSARY)
    else:
        from highway_srl.backends import make_backend
        from highway_srl.sim.ego_driver import idm_ego_backend

        world = make_backend(backend, scenario, traffic, adversarial, seed)
        if run is None:  # the built-in driver that only uses the Backend protocol
            driver = lambda w: (idm_ego_backend(w), [])  # noqa: E731
    return draw_episode(world, driver, steps, out, progress, overwrite)


def draw_episode(world, driver, steps: int, out: Path, progress: bool = False, overwrite: bool = False) -> list[Path]:
    """Drive world's one env with driver(world) -> ((lane, speed), text lines) for up to `steps` steps (to
    the episode's end), then write `out` (GIF) and a PNG of the middle frame beside it; returns both paths.
    overwrite False: never over a file that exists (the write refuses in one line)."""
    from highway_srl.experiments.runs import progress_bar

    bar = progress_bar(2 * steps + 1, "render (drive, then draw)", unit="frame", enabled=progress)
    try:
        frames = [capture(world)]
        for _ in range(steps):
            (lane, speed), text = driver(world)
            events = world.step(lane, speed)
            frames.append(capture(world, collision=bool(events.collision[0]), text=text))
            if bar is not None:
                bar.update()
            if bool(events.terminated[0] | events.truncated[0]):
                break
        if bar is not None:  # the episode may end early: the rest of the bar is the drawing
            bar.total = 2 * len(frames) - 1
            bar.refresh()
        on_frame = None if bar is None else lambda i: bar.update()
        gif = drawn(out, lambda tmp: save_gif(world.road, frames, tmp, on_frame=on_frame), overwrite)
        png = drawn(out.with_suffix(".png"), lambda tmp: save_png(world.road, frames[len(frames) // 2], tmp), overwrite)
    finally:
        if bar is not None:
            bar.close()
    return [gif, png]

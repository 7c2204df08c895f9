"""The vanishing detector: things that vanish or appear where nothing did in ID episodes."""

from __future__ import annotations

import numpy as np
import pytest

from oodmon.envs import Variant, parse_variant
from oodmon.errors import ConfigError, InvalidParameterError
from oodmon.monitor.detectors import DetectorSet, StepContext, Trajectory, VanishingDetector, collect, fit_detectors
from tests.helpers import RALLY, RandomButtons, ball_pictures, scores_along


def test_a_ball_hidden_mid_field_vanishes_and_appears_where_it_never_did():
    detector = VanishingDetector(grid=4, reach=4).fit([ball_pictures(RALLY)])
    # The background is the grey and the wall (the ball is at any pixel a few steps of 78).
    assert (detector.background[0] == 200).all() and (detector.background[1:] == 50).all()
    assert detector.events.sum() == 0  # an ID ball that moves 3 columns a step never vanishes
    assert scores_along(detector, ball_pictures(RALLY)) == [0.0] * (len(RALLY) - 1)
    # Hidden at columns 15-24 (tile columns 1 and 2 of 4, 10 pixels each): it vanishes from tile
    # column 1 on the way out and appears in tile column 2; back, the other way round: 2 a pass.
    scores = scores_along(detector, ball_pictures(RALLY, hidden=range(15, 25)))
    rises = [step for step in range(1, len(scores)) if scores[step] > scores[step - 1]]
    assert scores[-1] == 4 * 3 and len(rises) == 12
    assert rises[:2] == [5, 9]  # x = 15 is hidden at step 5; x = 27 (step 9) is the first seen again


def test_where_is_the_box_of_the_tiles_of_the_episodes_unseen_events_until_a_reset():
    detector = VanishingDetector(grid=4, reach=4).fit([ball_pictures(RALLY)])
    hidden = ball_pictures(RALLY, hidden=range(15, 25))
    scores_along(detector, Trajectory(hidden.observations[:6], hidden.actions[:5]))
    assert detector.where() is None  # (no event yet: the ball is seen at steps 0-4)
    scores_along(detector, Trajectory(hidden.observations[:7], hidden.actions[:6]))
    # vanished from tile column 1 (pixels 10-19) of tile row 1 (rows 5-9) of the 20x40 picture
    assert detector.where() == (5, 10, 5, 10, 20, 40)
    scores_along(detector, hidden)  # then appeared in tile column 2: the box spans both
    assert detector.where() == (5, 10, 5, 20, 20, 40) and detector.where().text() == (
        "rows 5-9, columns 10-29 of the 20x40 picture")
    detector.reset()
    assert detector.where() is None


def test_events_seen_in_id_episodes_and_other_scenes_are_not_counted():
    # Fitted on a ball that vanishes at the right edge and comes back at the left (a goal).
    goal = [*range(0, 38, 3)] * 4
    detector = VanishingDetector(grid=4, reach=4).fit([ball_pictures(goal)])
    assert detector.events[0].reshape(4, 4)[1, 3] == 3 and detector.events[1].reshape(4, 4)[1, 0] == 3
    assert detector.events.sum() == 6
    assert scores_along(detector, ball_pictures(goal)) == [0.0] * (len(goal) - 1)
    # A picture unlike the background at over half its pixels (a reset screen) is another scene:
    # the ball that seems to vanish into it and appear out of it is not counted.
    frames = ball_pictures([4, 7, 10, 13]).observations.copy()
    frames[2] = 0
    assert scores_along(detector, Trajectory(frames, np.zeros(3, np.int64))) == [0.0] * 3
    # Half its pixels unlike the background: read (the ball vanished, things appeared); one more: not.
    for unlike, read in ((400, True), (401, False)):
        frames[2] = detector.background
        frames[2].reshape(-1)[:unlike] = 0  # of 800 pixels
        assert (scores_along(detector, Trajectory(frames, np.zeros(3, np.int64)))[2] > 0) == read


@pytest.fixture(scope="module")
def pong():
    """Fitted on 6 ID games of Pong's first 300 decisions of a random policy."""
    return VanishingDetector().fit(collect(RandomButtons(), Variant("pong").make(), 6, seed=610_000, max_steps=300))


def test_pong_frozen_centre_passes_every_fresh_id_game_soon_after_it_freezes(pong):
    """The centre block of ``scripts/frozen_region.py`` (raw rows 80-149, columns 50-109), which
    only the ball crosses, held from step 100. When written: 10 fresh ID games ended at 0-1 events;
    the frozen games at 0 before the freeze, their first event 16-21 steps after it, one about every
    35 steps after (the ball's crossings), past the fresh games' 1 at 51-56 steps and at 6-7 by step 300."""
    fresh = [max(scores_along(pong, t)) for t in collect(RandomButtons(1), Variant("pong").make(), 10, seed=610_100,
                                                         max_steps=300)]
    assert max(fresh) <= 2
    for seed in (610_200, 610_201, 610_202):
        env = parse_variant("pong:frozen_region:top=80,left=50,height=70,width=60").make(onset_step=100)
        scores = np.array(scores_along(pong, collect(RandomButtons(seed), env, 1, seed=seed, max_steps=300)[0]))
        assert scores[100] == 0  # before the freeze: nothing unseen
        past = np.nonzero(scores > max(fresh))[0]
        assert len(past) and past[0] - 100 <= 100 and scores[-1] >= 4


def test_it_saves_and_loads_as_tensors_and_json_with_the_same_scores(pong, tmp_path):
    DetectorSet([pong]).save(tmp_path)
    loaded = DetectorSet.load(tmp_path)["vanishing"]
    assert loaded.fingerprint() == pong.fingerprint() and loaded.config() == pong.config()
    assert loaded.background.dtype == np.uint8 and loaded.background.shape == (84, 84)
    env = parse_variant("pong:frozen_region:top=80,left=50,height=70,width=60").make(onset_step=20)
    game = collect(RandomButtons(3), env, 1, seed=0, max_steps=200)[0]
    assert scores_along(loaded, game) == scores_along(pong, game)


@pytest.mark.parametrize("tensors, match", [
    ({"events": np.zeros((2, 144))}, "no 'background'"),
    ({"background": np.zeros((84, 84), np.uint8)}, "no 'events'"),
    ({"background": np.zeros(84, np.uint8), "events": np.zeros((2, 144))}, "must be a picture"),
    ({"background": np.zeros((8, 84), np.uint8), "events": np.zeros((2, 144))}, "at least 12 pixels a side"),
    ({"background": np.zeros((84, 84), np.uint8), "events": np.zeros((2, 16))}, "shape \\(2, 144\\)"),
    ({"background": np.zeros((84, 84), np.uint8), "events": np.full((2, 144), -1.0)}, "counts >= 0"),
])
def test_damaged_tensors_are_refused(tensors, match):
    with pytest.raises(ConfigError, match=match):
        VanishingDetector.from_state({}, tensors)


def test_bad_settings_pictures_and_short_episodes_are_refused():
    with pytest.raises(InvalidParameterError, match="grid=0"):
        VanishingDetector(grid=0)
    with pytest.raises(InvalidParameterError, match="reach=-1"):
        VanishingDetector(reach=-1)
    with pytest.raises(ConfigError, match="episodes of two steps or more"):
        VanishingDetector().fit([Trajectory(np.zeros((1, 84, 84), np.uint8), np.zeros(0, np.int64))])
    with pytest.raises(ConfigError, match="pictures of one shape"):
        VanishingDetector().fit([ball_pictures(RALLY), ball_pictures(RALLY, size=(20, 44))])
    with pytest.raises(ConfigError, match="12 x 12 tiles need pictures.* of at least 12 pixels a side"):
        VanishingDetector().fit([ball_pictures(RALLY, size=(11, 40))])
    detector = VanishingDetector(grid=4, reach=4).fit([ball_pictures(RALLY)])
    with pytest.raises(ConfigError, match="fitted on pictures of shape \\(20, 40\\)"):
        detector.score(StepContext(np.zeros((20, 44), np.uint8), 0))
    controller = lambda obs: int(obs[2] + obs[3] > 0)  # noqa: E731 (CartPole: a vector, no picture)
    with pytest.raises(ConfigError, match="the vanishing detector needs image observations"):
        fit_detectors(controller, Variant("cartpole").make(), detectors=["vanishing"], episodes=3)


def test_named_it_joins_the_default_set_and_combined_ranks_it_an_event_a_rank():
    """``--detector vanishing`` (fitted_when_named) fits a picture's default set, vanishing and a
    combined that ranks it beside frames and stillness, each event past the held-out record one
    rank (``UNIT_MEMBERS``); unnamed it is not fitted."""
    from oodmon.monitor.detectors.fitting import fitted_when_named

    fitted = fit_detectors(RandomButtons(), Variant("pong").make(), detectors=fitted_when_named("vanishing"),
                           episodes=3, max_steps=60)
    assert fitted.names == ["frames", "stillness", "vanishing", "combined"]
    combined = fitted["combined"]
    assert combined.members == ["frames", "stillness", "vanishing"] and combined.config()["scale"]["vanishing"] == 1.0
    assert combined.rank("vanishing", 1e6 + 3) - combined.rank("vanishing", 1e6) == pytest.approx(3, rel=1e-9)
    assert "vanishing" not in fit_detectors(RandomButtons(), Variant("pong").make(), episodes=3, max_steps=20).names


def test_pongs_default_set_holds_it_other_picture_envs_name_it():
    """DEFAULT_ADDS: Pong's default set (the task named) holds vanishing and its combined ranks it; the
    same pictures in an env oodmon has no variants of get frames and stillness alone, and vectors never."""
    from oodmon.monitor.detectors import default_detectors

    env = Variant("pong").make()
    assert default_detectors(RandomButtons(), env, "pong") == ("frames", "stillness", "vanishing", "combined")
    assert default_detectors(RandomButtons(), env, "MyPong-v0") == ("frames", "stillness", "combined")
    assert default_detectors(RandomButtons(), env) == ("frames", "stillness", "combined")
    controller = lambda obs: int(obs[2] + obs[3] > 0)  # noqa: E731
    assert "vanishing" not in default_detectors(controller, Variant("cartpole").make(), "cartpole")
    fitted = fit_detectors(RandomButtons(), env, episodes=3, max_steps=40, task="pong")
    assert fitted.names == ["frames", "stillness", "vanishing", "combined"]
    assert fitted["combined"].members == ["frames", "stillness", "vanishing"]


def test_a_vanishing_alarm_of_the_shipped_pong_ensemble_says_where_in_the_picture_a_part_froze(tmp_path):
    """A part of the camera frozen from decision 200 (the raw 210x160 frame's centre block, and the
    agent's third): the first alarm of the vanishing detector (at its first event never seen in ID
    games) names the box of its tiles, in the 84x84 picture the agent reads, at the frozen part:
    the ball vanishes as it enters it and appears as it leaves. Measured when written: the first
    events' tiles lay in the frozen part or within a tile of its border in 12 of 12 games (seeds
    800,000-800,002 of four parts, /tmp script); in the alarm's line, ``info["oodmon"]["region"]``,
    the alarm command's ``OODMON_REGION``, the log (format 12), which replay lists, and the Rerun
    file, a box over the frame from the alarm to the episode's end."""
    import json

    import rerun.chunk as rc

    from oodmon.agents import load
    from oodmon.errors import LogFormatError
    from oodmon.monitor import AlarmCommand, McapSink, MemorySink, Monitor, MonitoredEnv, RerunSink
    from oodmon.monitor.detectors import detectors_for
    from oodmon.monitor.detectors.vanishing import REACH
    from oodmon.replay import read_log
    from oodmon.replay.reader import _first_alarm_region, _raised
    from tests.helpers import run_cli

    agent = load("pong", "ensemble")
    for top, left, height, width in ((80, 50, 70, 60), (0, 107, 210, 53)):
        out, sink = tmp_path / f"{left}.txt", MemorySink()
        command = AlarmCommand(f'echo "$OODMON_REGION" >> {out}')
        monitor = Monitor(agent, 0.5, detectors=detectors_for(agent), detector="vanishing",
                          sinks=[sink, McapSink(tmp_path / f"{left}.mcap"), RerunSink(tmp_path / f"{left}.rrd")],
                          callbacks=[command])
        env = MonitoredEnv(parse_variant(f"pong:frozen_region:top={top},left={left},height={height},width={width}")
                           .make(onset_step=200), monitor)
        env.reset(seed=800_000)
        for _ in range(300):
            info = env.step()[-1]["oodmon"]
            if sink.alarms:
                break
        env.close()
        assert command.close() == "ran 1 time (episode 0), each exited 0"
        (alarm,) = sink.alarms
        assert alarm.step > 200 and alarm.cause == "vanishing" and alarm.region is not None
        region = alarm.region
        assert info["region"] == region._asdict() == json.loads(out.read_text())
        assert f"; cause: vanishing; where: {region.text()}" in alarm.text() and region[4:] == (84, 84)
        # the frozen part in the 84x84 picture, and the pixels within a ball's reach of it
        rows = (top * 84 / 210 - REACH, (top + height) * 84 / 210 + REACH)
        columns = (left * 84 / 160 - REACH, (left + width) * 84 / 160 + REACH)
        assert rows[0] <= region.top and region.top + region.height <= rows[1], (region, rows)
        assert columns[0] <= region.left and region.left + region.width <= columns[1], (region, columns)
        assert region.height * region.width <= 14 * 14  # (one or a few tiles, not the whole picture)
        (logged,) = read_log(tmp_path / f"{left}.mcap").interrupted  # (closed at the alarm, inside the game)
        assert logged.first_alarm_region == region
        (row,) = json.loads(run_cli("replay", "--episodes", "--json", str(tmp_path / f"{left}.mcap")).stdout)
        assert row["first_alarm_region"] == region.text() and row["first_alarm_cause"] == "vanishing"
        drawn = rc.RrdReader(tmp_path / f"{left}.rrd").stream().collect().reader("step").to_pandas()
        boxes = drawn.dropna(subset=["/frame/alarm_region:Boxes2D:labels"])
        assert list(boxes["step"]) == [alarm.step, logged.length]  # drawn at the alarm, cleared at the episode's end
        first = boxes.iloc[0]
        assert list(first["/frame/alarm_region:Boxes2D:labels"]) == ["alarm: vanishing"]
        assert [list(v) for v in first["/frame/alarm_region:Boxes2D:centers"]] == [
            [region.left + region.width / 2, region.top + region.height / 2]]
        assert [list(v) for v in first["/frame/alarm_region:Boxes2D:half_sizes"]] == [
            [region.width / 2, region.height / 2]]
        assert len(boxes.iloc[1]["/frame/alarm_region:Boxes2D:labels"]) == 0
    # a torn log's running episode: from the step message that raised it (format 11's ``raised``)
    steps = [{"step": 230, "raised": {"cause": "vanishing", "readings": [], "readings_steps": 1,
                                      "region": region._asdict()}}]
    assert _raised(tmp_path, 0, steps, 230)["first_alarm_region"] == region._asdict()
    for damaged in ("x", {**region._asdict(), "top": -1}, {**region._asdict(), "height": 0},
                    {**region._asdict(), "top": 80}, {"top": 1}):
        with pytest.raises(LogFormatError, match="first_alarm_region="):
            _first_alarm_region(tmp_path, {"episode": 0, "first_alarm_region": damaged})
        assert _raised(tmp_path, 0, [{"step": 230, "raised": {"cause": "vanishing", "region": damaged}}], 230) == {
            "first_alarm_cause": "vanishing"}
    assert _first_alarm_region(tmp_path, {"episode": 0}) is None  # a log older than format 12


def test_the_regions_script_says_each_first_alarms_cause_and_box_and_whether_it_lies_at_the_frozen_part(
        monkeypatch, capsys):
    """``scripts/alarm_regions.py``, whose figures docs/detectors.md gives (one game of the frozen
    centre here: the ensemble under its default alarm, combined > 3.95619)."""
    from tests.helpers import load_script

    script = load_script("alarm_regions")[1]
    monkeypatch.setattr("sys.argv", ["alarm_regions", "--games", "1", "--parts", "centre", "--max-steps", "260"])
    script.main()
    assert capsys.readouterr().out.splitlines() == [
        "pong/ensemble: combined > 3.95619, frozen from decision 200, at most 260",
        "centre         game 0: +12 decisions, vanishing, rows 28-34, columns 21-34 of the 84x84 picture, within "
        "10 pixels of the part",
        "first alarms by vanishing 1; 1 named a region, 1 of them within 10 pixels of the frozen part"]

"""The link model (sitl/world/linkmodel.py): loss, burst outages, latency and jitter, the bandwidth cap, its counters,
its seeding, and the drone's ``--link`` option.

Statistical checks use fixed seeds and bounds of four standard deviations of the estimate: deterministic, and
tight enough that a model a few percent off its setting fails."""

from __future__ import annotations

import itertools
import math
import subprocess
import sys

import numpy as np
import pytest

from sitl.cli import main as sitl_main
from sitl.world.linkmodel import (
    DIRECTIONS,
    LINK_CLASSES,
    MAX_QUEUE_S,
    LinkChannel,
    LinkCounters,
    LinkImpairment,
    LinkProfile,
    channel_seed,
    counters_by_class,
    drone_channels,
    link_arguments,
    link_profile,
    parse_link_option,
    total_counters,
)
from tests.unit.link_cases import PAIR_CASES, VALUE_CASES

pytestmark = pytest.mark.timeout(60)


def channel(seed: int = 1, **settings: float) -> LinkChannel:
    return LinkChannel(LinkImpairment(**settings), np.random.default_rng(seed))


def send_every(chan: LinkChannel, period_s: float, count: int, size_bytes: int = 40) -> list[float | None]:
    return [chan.transmit(k * period_s, size_bytes) for k in range(count)]


def lost_runs(fates: list[float | None]) -> list[int]:
    """Lengths of the runs of consecutive lost frames."""
    runs, current = [], 0
    for fate in fates:
        if fate is None:
            current += 1
        elif current:
            runs.append(current)
            current = 0
    return runs + ([current] if current else [])


# ---- loss --------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("loss", [0.05, 0.2, 0.5])
def test_the_loss_rate_converges_to_the_setting(seed: int, loss: float) -> None:
    # GIVEN a channel losing frames at random, WHEN it carries N frames
    n = 20_000
    chan = channel(seed, loss=loss)
    lost = sum(fate is None for fate in send_every(chan, 0.01, n))
    # THEN the number lost lies within 4 standard deviations of the binomial's mean
    assert abs(lost - n * loss) <= 4 * math.sqrt(n * loss * (1 - loss))
    counters = chan.counters()
    assert counters.lost_random == lost and counters.lost_burst == counters.lost_queue == 0
    assert counters.frames_offered == n and counters.frames_delivered == n - lost


def test_losses_are_independent_frame_to_frame_without_bursts() -> None:
    # A memoryless loss makes a frame's fate independent of the one before: P(lost | previous lost) = loss.
    fates = send_every(channel(5, loss=0.3), 0.01, 40_000)
    after_lost = [fates[k] is None for k in range(1, len(fates)) if fates[k - 1] is None]
    n = len(after_lost)
    assert abs(sum(after_lost) - 0.3 * n) <= 4 * math.sqrt(n * 0.3 * 0.7)


def test_a_perfect_setting_is_perfect_and_a_zero_loss_link_loses_nothing() -> None:
    assert LinkImpairment().is_perfect and LinkProfile().is_perfect
    assert not LinkImpairment(loss=0.01).is_perfect and not LinkImpairment(latency_ms=1).is_perfect
    assert not LinkImpairment(bandwidth_bps=1e6).is_perfect
    assert LinkImpairment(burst_good_s=1, burst_bad_s=1, burst_loss=0).is_perfect  # outages that lose nothing
    fates = send_every(channel(latency_ms=10), 0.02, 1000)
    assert all(f is not None and f == pytest.approx(k * 0.02 + 0.010) for k, f in enumerate(fates))


# ---- bursts (Gilbert-Elliott) ------------------------------------------------------------------------------------

GOOD_S, BAD_S = 0.5, 0.2
BURST_SPAN_S = 1000.0  # about 1400 outages: the mean of their lengths has a standard deviation of 2.7 %


@pytest.mark.parametrize("rate_hz", [100.0, 400.0])
def test_outages_last_burst_bad_s_on_average_whatever_the_frame_rate(rate_hz: float) -> None:
    # GIVEN a channel with outages (every frame lost while bad) and no other loss
    chan = channel(7, burst_good_s=GOOD_S, burst_bad_s=BAD_S)
    # WHEN frames are sent at rate_hz for BURST_SPAN_S
    period = 1.0 / rate_hz
    fates = send_every(chan, period, int(BURST_SPAN_S * rate_hz))
    runs = lost_runs(fates)
    # THEN the outages, measured by the frames they swallowed, last burst_bad_s on average (a run of k lost frames
    # spans k periods; an outage shorter than a period may swallow no frame, which biases the mean up by at most
    # about half a period)
    n = len(runs)
    mean_s = sum(runs) * period / n
    assert abs(mean_s - BAD_S) <= 4 * BAD_S / math.sqrt(n) + period / 2
    # AND the time between them averages burst_good_s, so the share lost is bad / (good + bad)
    lost_share = sum(runs) / len(fates)
    assert lost_share == pytest.approx(BAD_S / (GOOD_S + BAD_S), abs=0.015)
    assert BURST_SPAN_S / n == pytest.approx(GOOD_S + BAD_S, rel=4 / math.sqrt(n))
    assert chan.counters().lost_burst == sum(runs) and chan.counters().lost_random == 0


def test_outages_fall_at_the_same_times_whatever_the_traffic() -> None:
    # The state timeline has its own generator: a fast and a slow sender on the same seed see the same outages.
    fast, slow = channel(9, burst_good_s=1.0, burst_bad_s=0.3), channel(9, burst_good_s=1.0, burst_bad_s=0.3)
    fast_fates = send_every(fast, 0.001, 200_000)
    slow_fates = send_every(slow, 0.01, 20_000)
    assert [fast_fates[10 * k] is None for k in range(20_000)] == [f is None for f in slow_fates]


def test_a_partial_burst_loss_loses_that_share_of_the_frames_sent_in_outages() -> None:
    chan = channel(11, burst_good_s=0.5, burst_bad_s=0.5, burst_loss=0.5)
    send_every(chan, 0.005, 100_000)
    counters = chan.counters()
    # half the time bad, half the frames sent then lost: a quarter of all
    assert counters.lost_burst / counters.frames_offered == pytest.approx(0.25, abs=0.02)


# ---- latency, jitter, reordering ---------------------------------------------------------------------------------


def test_jitter_is_a_normal_around_the_latency_truncated_at_zero_delay() -> None:
    # GIVEN 40 ms latency with 20 ms jitter, WHEN 20 000 frames cross
    n = 20_000
    delays = np.array([f - k * 0.01 for k, f in enumerate(send_every(channel(3, latency_ms=40, jitter_ms=20), 0.01, n))
                       if f is not None])  # fmt: skip
    # THEN no frame arrives before it was sent, and the delays are the normal N(40, 20) ms cut at 0: its mean is
    # mu + sigma * pdf(2) / (1 - cdf(-2)) = 41.105 ms, its standard deviation 18.79 ms
    assert delays.min() >= 0
    assert delays.mean() * 1000 == pytest.approx(41.105, abs=4 * 18.79 / math.sqrt(n))
    assert delays.std() * 1000 == pytest.approx(18.79, rel=0.03)
    # AND about half land within 13.5 ms of the latency (the normal's central 50 %, +-0.674 sigma)
    central = np.mean(np.abs(delays * 1000 - 40) <= 0.674 * 20)
    assert central == pytest.approx(0.5 / 0.97725, abs=4 * 0.5 / math.sqrt(n))


def test_with_no_latency_the_jitter_is_a_half_normal_with_no_lump_at_zero() -> None:
    # Truncation redraws a negative delay instead of clamping it, which would deliver half the frames at exactly
    # zero delay.
    n = 20_000
    fates = send_every(channel(4, jitter_ms=10), 0.01, n)
    delays = np.array([f - k * 0.01 for k, f in enumerate(fates) if f is not None])
    assert np.count_nonzero(delays <= 1e-12) == 0
    assert delays.mean() * 1000 == pytest.approx(10 * math.sqrt(2 / math.pi), abs=4 * 6.03 / math.sqrt(n))


def test_independent_delays_reorder_frames_and_no_jitter_keeps_the_order() -> None:
    jittery = send_every(channel(5, latency_ms=40, jitter_ms=20), 0.005, 2000)
    arrivals = [f for f in jittery if f is not None]
    overtaken = sum(1 for a, b in itertools.pairwise(arrivals) if b < a)
    # consecutive frames 5 ms apart, delays with a 20 ms spread: a neighbour overtakes often, not always
    assert 0.2 * len(arrivals) < overtaken < 0.8 * len(arrivals)
    steady = [f for f in send_every(channel(5, latency_ms=40, loss=0.1), 0.005, 2000) if f is not None]
    assert steady == sorted(steady)


def test_delay_counters_add_up() -> None:
    chan = channel(6, loss=0.1, latency_ms=40, jitter_ms=20)
    fates = send_every(chan, 0.01, 5000)
    counters = chan.counters()
    delays = [f - k * 0.01 for k, f in enumerate(fates) if f is not None]
    assert counters.frames_delivered == len(delays) == counters.delayed
    assert counters.total_delay_s == pytest.approx(sum(delays))
    assert counters.max_delay_s == pytest.approx(max(delays))
    assert counters.mean_delay_s == pytest.approx(sum(delays) / len(delays))
    assert counters.frames_offered == counters.frames_delivered + counters.frames_lost


# ---- bandwidth ---------------------------------------------------------------------------------------------------


def test_frames_queue_behind_each_other_at_the_air_rate_and_a_full_queue_drops() -> None:
    # GIVEN a 64 kbit/s cap and 10 ms latency: a 1000-byte frame takes 0.125 s on the air
    chan = channel(latency_ms=10, bandwidth_bps=64_000)
    # WHEN 20 such frames are offered at once
    fates = [chan.transmit(0.0, 1000) for _ in range(20)]
    # THEN they leave one after another; the ones that would wait more than MAX_QUEUE_S (1 s) are dropped
    kept = int(MAX_QUEUE_S / 0.125) + 1  # waits 0, 0.125, ..., 1.0 s
    assert fates[:kept] == pytest.approx([0.125 * (k + 1) + 0.010 for k in range(kept)])
    assert fates[kept:] == [None] * (20 - kept)
    assert chan.counters().lost_queue == 20 - kept
    # AND once the queue has drained a frame goes straight on the air again
    assert chan.transmit(5.0, 1000) == pytest.approx(5.135)


def test_a_rate_under_the_cap_only_adds_the_time_on_the_air() -> None:
    chan = channel(bandwidth_bps=100_000)
    fates = send_every(chan, 0.01, 1000, size_bytes=50)  # 4 ms on the air every 10 ms
    assert all(f == pytest.approx(k * 0.01 + 0.004) for k, f in enumerate(fates))
    assert chan.counters().lost_queue == 0


def test_an_offered_rate_over_the_cap_is_cut_to_the_cap() -> None:
    chan = channel(bandwidth_bps=32_000)  # 100-byte frames: 25 ms each, offered every 10 ms for 100 s
    fates = send_every(chan, 0.01, 10_000, size_bytes=100)
    delivered = sum(f is not None for f in fates)
    assert delivered == pytest.approx(100 / 0.025, rel=0.01)
    assert max(f - k * 0.01 for k, f in enumerate(fates) if f is not None) <= MAX_QUEUE_S + 0.025 + 1e-9


# ---- determinism and seeding -------------------------------------------------------------------------------------

IMPAIRED = LinkImpairment(loss=0.1, burst_good_s=2, burst_bad_s=0.5, latency_ms=30, jitter_ms=10)


def decisions(profile: LinkProfile, seed: int) -> dict[tuple[str, str], list[float | None]]:
    channels = drone_channels(profile, seed=seed)
    return {key: send_every(chan, 0.02, 2000) for key, chan in channels.items()}


def test_the_same_seed_gives_the_same_decisions_and_another_seed_others() -> None:
    profile = LinkProfile(gcs=IMPAIRED, api=IMPAIRED, neighbour=IMPAIRED)
    first = decisions(profile, seed=5)
    assert first == decisions(profile, seed=5)
    assert first != decisions(profile, seed=6)
    # every class and direction draws its own: no two channels decide alike
    fates = [tuple(v) for v in first.values()]
    assert len(fates) == len(LINK_CLASSES) * len(DIRECTIONS) == len(set(fates))


def test_a_drone_s_draws_do_not_depend_on_the_other_drones_or_classes() -> None:
    # Channels are seeded from (the drone's seed, class, direction) alone: a drone added to the swarm, or another
    # class impaired, leaves a channel's decisions unchanged.
    alone = decisions(LinkProfile(neighbour=IMPAIRED), seed=7)
    with_others = decisions(LinkProfile(gcs=IMPAIRED, neighbour=IMPAIRED), seed=7)
    assert alone[("neighbour", "up")] == with_others[("neighbour", "up")]
    seeds = {str(channel_seed(s, c, d).entropy) for s in range(3) for c in LINK_CLASSES for d in DIRECTIONS}
    assert len(seeds) == 3 * len(LINK_CLASSES) * len(DIRECTIONS)


def test_a_drone_s_counters_come_by_class_and_direction() -> None:
    channels = drone_channels(LinkProfile(gcs=LinkImpairment(loss=0.5)), seed=1)
    channels[("gcs", "up")].transmit(0.0, 10)
    snapshot = counters_by_class(channels)
    assert set(snapshot) == {("gcs", "up"), ("gcs", "down")}
    assert snapshot[("gcs", "up")].frames_offered == 1 and snapshot[("gcs", "down")] == LinkCounters()


def test_only_impaired_classes_get_channels() -> None:
    assert drone_channels(LinkProfile(), seed=0) == {}
    assert set(drone_channels(LinkProfile(api=IMPAIRED), seed=0)) == {("api", "up"), ("api", "down")}


def test_counters_merge_into_totals() -> None:
    a = LinkCounters(frames_offered=10, frames_delivered=7, lost_random=2, lost_queue=1, delayed=7,
                     total_delay_s=0.7, max_delay_s=0.2)  # fmt: skip
    b = LinkCounters(frames_offered=5, frames_delivered=4, lost_burst=1, delayed=3, total_delay_s=0.3,
                     max_delay_s=0.4)  # fmt: skip
    total = total_counters([a, b])
    assert total == LinkCounters(frames_offered=15, frames_delivered=11, lost_random=2, lost_burst=1, lost_queue=1,
                                 delayed=10, total_delay_s=1.0, max_delay_s=0.4)  # fmt: skip
    assert total.frames_lost == 4


# ---- validation and the --link option ----------------------------------------------------------------------------


@pytest.mark.parametrize(("key", "text", "message"), VALUE_CASES)
def test_each_setting_is_checked_with_one_line(key: str, text: str, message: str | None) -> None:
    if message is None:
        assert link_profile([f"gcs:{key}={text}"]).gcs == LinkImpairment(**{key: float(text)})
        return
    with pytest.raises(ValueError) as caught:
        link_profile([f"gcs:{key}={text}"])
    assert str(caught.value) == message
    if text not in ("abc",):
        with pytest.raises(ValueError) as direct:
            LinkImpairment(**{key: float(text)})
        assert str(direct.value) == message.replace(f"got {text}", f"got {float(text):g}")


@pytest.mark.parametrize(("values", "message"), PAIR_CASES)
def test_half_a_burst_setting_is_refused(values: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=r"^burst_good_s and burst_bad_s") as caught:
        LinkImpairment(**values)
    assert str(caught.value) == message
    text = ",".join(f"{k}={v:g}" for k, v in values.items())
    with pytest.raises(ValueError) as parsed:
        link_profile([f"api:{text}"])
    assert str(parsed.value) == f"api: {message}"


def test_link_options_name_a_class_or_all_and_later_keys_win() -> None:
    profile = link_profile(["all:loss=0.2,latency_ms=40", "neighbour:latency_ms=200,jitter_ms=50"])
    assert profile.gcs == profile.api == LinkImpairment(loss=0.2, latency_ms=40)
    assert profile.neighbour == LinkImpairment(loss=0.2, latency_ms=200, jitter_ms=50)
    assert parse_link_option("api: loss = 0.1 ") == (("api",), {"loss": 0.1})
    for bad, message in [
        ("gcs", "must be CLASS:key=value[,key=value...], got 'gcs'"),
        ("radio:loss=0.1", "link class must be gcs, api, neighbour or all, got 'radio'"),
        ("gcs:loss", "must be CLASS:key=value[,key=value...], got 'gcs:loss'"),
        ("gcs:speed=3", "unknown key 'speed' (keys: loss, latency_ms, jitter_ms, burst_good_s, burst_bad_s, "
                        "burst_loss, bandwidth_bps)"),
    ]:  # fmt: skip
        with pytest.raises(ValueError) as caught:
            link_profile([bad])
        assert str(caught.value) == message


@pytest.mark.parametrize(
    "profile",
    [
        LinkProfile(),
        LinkProfile(gcs=IMPAIRED, api=IMPAIRED, neighbour=IMPAIRED),
        LinkProfile(neighbour=LinkImpairment(latency_ms=200.0, jitter_ms=50.0)),
        LinkProfile(api=LinkImpairment(loss=0.1 + 0.2, bandwidth_bps=57_600), gcs=IMPAIRED),
    ],
)
def test_link_arguments_give_a_drone_the_same_profile_back(profile: LinkProfile) -> None:
    argv = link_arguments(profile)
    assert argv[0::2] == ["--link"] * (len(argv) // 2)
    assert link_profile(argv[1::2]) == profile


def test_sitl_refuses_a_bad_link_with_one_line_and_exit_code_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert sitl_main(["--link", "gcs:loss=1.5"]) == 2
    assert capsys.readouterr().err == "sitl: error: --link: loss must be in [0, 1], got 1.5\n"
    assert sitl_main(["--link", "all:latency_ms=-3", "--no-mavlink"]) == 2
    assert capsys.readouterr().err == "sitl: error: --link: latency_ms must be >= 0, got -3\n"


def test_sitl_as_a_process_says_the_same() -> None:
    result = subprocess.run([sys.executable, "-m", "sitl.cli", "--link", "neighbour:jitter_ms=-1"],
                            capture_output=True, text=True, timeout=50)  # fmt: skip
    assert result.returncode == 2
    assert result.stderr == "sitl: error: --link: jitter_ms must be >= 0, got -1\n"

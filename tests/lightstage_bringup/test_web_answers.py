"""The page shows a calibrated classifier's answers as what they are, in headless Chromium:
an accepted one with its probability, a "not sure" one and an "unknown object" each in words
(and colour), with the exposures it took of its budget, live and in the history.

The results are published on /lightstage/result as the classifier node publishes them (its
ClassificationResult with probabilities, decision, novelty, budget), beside the page server
alone: what the page makes of them is under test, not the classifier.
"""
import asyncio

import pytest

from helpers.browser import Browser, screenshot_stats
from helpers.suite import GraphClient, fresh_domain_id
from helpers.web import served

pytestmark = [pytest.mark.ros, pytest.mark.process]

NAMES = ['banana-fake', 'banana-real', 'orange-fake', 'orange-real']
ANSWERS = [
    # label, probabilities, decision, novelty, images used, budget
    ('banana-real', [0.02, 0.97, 0.005, 0.005], 'accepted', 0.3, 4, 8),
    ('orange-real', [0.01, 0.03, 0.39, 0.57], 'unsure', 0.6, 8, 8),
    ('banana-fake', [0.41, 0.35, 0.14, 0.10], 'unknown', 2.3, 8, 8),
]


def _result(label, probabilities, decision, novelty, used, budget, stamp_s):
    from lightstage_interfaces.msg import ClassificationResult
    msg = ClassificationResult(label=label, class_names=NAMES, decision=decision,
                               probabilities=probabilities, novelty=novelty, images_used=used,
                               images_budget=budget, calibrated=True,
                               scores=[p - 0.5 for p in probabilities], acquisition_ms=90.0,
                               compute_ms=2.0)
    msg.header.stamp.sec = stamp_s
    return msg


def test_unsure_and_unknown_answers_show_on_the_page_as_such(tmp_path):
    from lightstage_interfaces.msg import ClassificationResult
    domain_id = fresh_domain_id()
    client = GraphClient(domain_id)
    try:
        pub = client.node.create_publisher(ClassificationResult, '/lightstage/result', 10)
        with served('web', domain_id) as (_, url):
            client.spin_until(lambda: pub.get_subscription_count() > 0, 30.0,
                              "the page's reader of /lightstage/result")
            for i, answer in enumerate(ANSWERS):
                pub.publish(_result(*answer, stamp_s=1_700_000_000 + i))

            async def steps(page_url):
                browser = Browser(tmp_path / 'chromium-profile')
                try:
                    await browser.start()
                    page = await browser.page()
                    await page.send('Page.navigate', url=page_url + '/')
                    await page.wait_for("typeof state !== 'undefined' && state !== null "
                                        "&& state.history.length === 3", 30, 'the three answers')
                    shown = {}
                    rows = await page.evaluate(
                        "[...document.querySelectorAll('#history tbody tr')].map(r => "
                        "[r.dataset.id, r.children[1].dataset.decision, r.children[1].textContent, "
                        "r.children[2].textContent])")
                    for row_id, decision, _, _ in rows:   # select each entry in turn
                        await page.evaluate(
                            f"document.querySelector('#history tr[data-id=\"{row_id}\"]').click()")
                        await page.wait_for(
                            f"document.getElementById('decision').dataset.decision === '{decision}'",
                            10, f'the {decision} answer shown')
                        shown[decision] = await page.evaluate(
                            "[document.getElementById('decision').textContent, "
                            "getComputedStyle(document.getElementById('decision')).backgroundColor, "
                            "document.getElementById('times').textContent, "
                            "document.querySelectorAll('#scores .bar.probability').length]")
                        await page.screenshot(tmp_path / f'web_{decision}.png')
                        if decision == 'unsure':
                            png = await page.screenshot(tmp_path / 'web_unsure.png')
                        # back to the newest before the next
                        await page.evaluate(
                            f"document.querySelector('#history tr[data-id=\"{row_id}\"]').click()")
                    return rows, shown, png
                finally:
                    await browser.close()

            rows, shown, png = asyncio.run(steps(url))
    finally:
        client.close()
    # the history, newest first: each answer in words, with its exposures of the budget
    assert [(d, text, exp) for _, d, text, exp in rows] == [
        ('unknown', 'unknown object', '8'),
        ('unsure', 'not sure (orange-real 57 %)', '8'),
        ('accepted', 'banana-real 97 %', '4 of 8')]
    text, background, times, bars = shown['unsure']
    assert text == ('not sure: orange-real 57.0 %, orange-fake 39.0 % — look again or ask a '
                    'person') and bars == 4
    assert times.startswith('8 exposures')
    text, unknown_background, _, _ = shown['unknown']
    assert text == 'unknown object: unlike every trained class (novelty 2.30) — not banana-fake'
    text, accepted_background, times, _ = shown['accepted']
    assert text == 'accepted: 97.0 % sure' and times.startswith('4 of 8 exposures')
    # told apart by colour too: unsure and unknown are marked, and not alike
    assert len({background, unknown_background, accepted_background}) == 3
    stats = screenshot_stats(png)
    assert stats['std'] > 20 and stats['colours'] > 100, stats

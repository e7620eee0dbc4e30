"""What a person looks at: the live view, a local web page that shows the swarm as the ground station knows it
(docs/view.md), and the flight report written after a flight (metrics.json, plots, summary, report.html).

``scene`` turns what the ground station holds (telemetry, slots, losses, obstacles) into one JSON-ready frame, pure;
``server`` serves the page and streams frames to every browser tab that watches, in a thread of its own, so the
simulation never waits for a browser; ``static/`` is the page itself, with the JavaScript it needs shipped inside
the package (nothing is fetched at run time). ``report`` writes the report; ``replay`` and ``report_page`` make its
page, which draws with the live view's own script.
"""

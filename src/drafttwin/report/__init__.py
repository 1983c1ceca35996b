"""The study report: a self-contained HTML page and CSV tables (Table 2 / Table 3 / Fig. 7 /
Fig. 8 analogues, honest metrics, agreement with the paper).

``write_report(out_dir, results, predictions)`` writes them; ``results`` is the study's
results dictionary, ``predictions`` the test part's measured, true and predicted speeds.
"""

from drafttwin.report.writer import render_html, write_report, write_study

__all__ = ["render_html", "write_report", "write_study"]

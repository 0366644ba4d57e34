"""The schema version of every message and document the bench writes, in one place.

Bump a version here when the layout it names changes (a field added, renamed or re-meant), so
readers can refuse what they do not understand.
"""

from __future__ import annotations

# protocol.messages: the second element of every msgpack array on the wire.
MESSAGE_SCHEMA_VERSION = 1
# hil sim's summary.json and the [provenance] of every scenario.resolved.toml.
SIM_SCHEMA_VERSION = 1
# hil run's summary.json (hil.analysis.analyze). 3: verdict.blocking gone; samples_judged one per
# control period when the controller runs below the plant's sample rate.
RUN_SCHEMA_VERSION = 3
# report.json (hil report, hil.analysis.report.build).
REPORT_SCHEMA_VERSION = 3  # 3: verdict.blocking gone
# compare.json (hil compare, hil.analysis.report.compare).
COMPARE_SCHEMA_VERSION = 1
# sweep.json (hil sweep, hil.sweep.outputs).
SWEEP_SCHEMA_VERSION = 2  # 2: coverage
# margin.json (hil margin, hil.analysis.margin.record).
MARGIN_SCHEMA_VERSION = 1

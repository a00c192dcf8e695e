"""Error assessment and collision checks (Huang & Oliver 1994 section 3.2, plus the
collision checks machinists ask for)."""

from sim.checks.findings import KINDS, Finding, findings_json, merge_findings

__all__ = ["KINDS", "Finding", "findings_json", "merge_findings"]

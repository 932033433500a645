"""Shared by the RML benchmark scripts: the RML runs of chosen batches of a suite."""


def rml_scenarios(parser, suite, batch_list):
    """The scenarios of ``suite`` in the comma-separated ``batch_list`` identified by the RML.

    A batch that has no RML run is a usage error (``parser.error`` names it).
    """
    from manualcontrol.bench.scenarios import load_suite

    batches = batch_list.split(",")
    scenarios = [
        s
        for s in load_suite(suite).scenarios()
        if s.batch in batches and s.estimator["name"] == "rml"
    ]
    missing = sorted(set(batches) - {s.batch for s in scenarios})
    if missing:
        parser.error(f"batches without an RML run in {suite}: {', '.join(missing)}")
    return batches, scenarios

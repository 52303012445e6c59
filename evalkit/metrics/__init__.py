"""Metrics: bundles against exact bundles (`bundles`)."""

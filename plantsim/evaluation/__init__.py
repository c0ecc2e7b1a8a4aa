"""Evaluation: cloud-to-mesh metrics (:mod:`.metrics`), plant traits (:mod:`.traits`), a scan
against its truth (:mod:`.evaluate`) and studies of error against run time (:mod:`.study`)."""

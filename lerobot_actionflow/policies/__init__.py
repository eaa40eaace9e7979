"""LeRobot policy plugins (thin glue from LeRobot batches onto the core ``flow`` and ``nn``)."""

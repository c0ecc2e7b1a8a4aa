"""Real hardware: the Dynamixel servo turntable (:mod:`.dynamixel`). Never imported by
``import plantsim``; the drivers load their SDKs only when they connect."""

"""Serial drivers: the SICK PLS / LMS 2xx laser (:mod:`icploc.drivers.sick`) and the
ActivMedia PowerBot / Pioneer base (:mod:`icploc.drivers.powerbot`), their pure protocol
codecs (:mod:`~icploc.drivers.sick_protocol`, :mod:`~icploc.drivers.arcos_protocol`) and
raw-byte recording (:mod:`~icploc.drivers.recording`)."""

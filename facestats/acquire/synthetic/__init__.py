"""The synthetic stand-in for a real capture: population, textures, simulators (the faces are in :mod:`facestats.face`).

No face database can be downloaded, so the embedded default store is made from a
synthetic population drawn from the published statistics
(:mod:`~facestats.acquire.synthetic.population`) on ICT-FaceKit's face
(:mod:`~facestats.face.ict`; the procedural head of
:mod:`~facestats.face.procedural` with ``--face procedural``), whose dome and contact-sensor
captures are simulated (:mod:`~facestats.acquire.synthetic.simulate`) with the
skin model of :mod:`facestats.model` as the forward model, and then pushed
through the real fit pipeline.
"""

"""System-identification experiments: the Volterra series benchmark (thesis 6.5,
:mod:`.volterra`, :mod:`.volterra_report`) and the inverse-dynamics benchmark (thesis 3.4,
:mod:`.inverse_dynamics`, :mod:`.inverse_dynamics_report`)."""

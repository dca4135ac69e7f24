"""Parameters of the DVS pixel block, with the paper's defaults."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from evsda.graph import BlockParams


class DvsPixelParams(BlockParams):
    """Parameters of :class:`~evsda.blocks.pixel.block.DvsPixel` (paper Sec. 2.3-2.5)."""

    implementation: Literal["fast", "reference"] = Field(
        "fast", description="'fast': event-driven, exact on the time grid, for full sensors; 'reference': dense "
                            "time stepping exactly as the paper writes it, for small sensors and checks [-]")
    # 1 us: the event-driven pixels cost per event and input change, not per step, so 10 us is no cheaper
    # (and 100 us moves streaking stars' counts by 10 % per star): docs/speed.md, "Speed against error"
    time_step_s: float = Field(1e-6, gt=0, le=0.1, description="Pixel time step dt; event times are multiples of it "
                                                               "(rounded to whole nanoseconds) [s]")
    # photoreceptor (Eq. 12-14)
    quantum_efficiency: float = Field(0.6, gt=0, le=1, description="Quantum efficiency eta of Eq. 12 [1]")
    reference_current_A: float = Field(1e-15, gt=0, description="I_ref: one unit of the dimensionless current scale "
                                                                "of Eqs. 14, 16 and 20 (the paper's digital-number scale) [A]")
    linear_knee: float = Field(5.0, gt=1, description="Normalised current below which the log response of Eq. 14 "
                                                      "is linear (paper: 5) [1]")
    knee_at_dark_current: bool = Field(False, description="Eq. 14 logarithmic down to the dark current: Y = ln x for "
                                                          "every current when the dark current is positive (a real DVS "
                                                          "photoreceptor; the linear piece is then never reached); "
                                                          "false: the paper's knee at linear_knee I_ref [-]")
    # dark current (Eq. 15)
    temperature_K: float = Field(300.0, gt=0, le=500, description="Photodiode (die) temperature [K]")
    dark_current_density_A_m2: float = Field(1e-5, ge=0, description="Dark current per photodiode area at "
                                                                     "dark_reference_temperature_K (1e-5 A/m^2 = 1 nA/cm^2) [A m^-2]")
    dark_reference_temperature_K: float = Field(300.0, gt=0, description="Temperature at which the dark current "
                                                                         "density is given [K]")
    dark_activation_energy_eV: float = Field(0.56, ge=0, le=2, description="Arrhenius activation energy E_a of the "
                                                                           "dark current (Eq. 15) [eV]")
    # low-pass filter (Eq. 16)
    cutoff_max_hz: float = Field(3000.0, ge=0, description="Maximum photoreceptor 3 dB cutoff f_3dB,max; 0 disables "
                                                           "the filter (paper: ~3 kHz after Lichtsteiner 2008) [Hz]")
    cutoff_model: Literal["paper", "proportional", "power"] = Field(
        "paper", description="Cutoff law: 'paper' = Eq. 16 as printed, (Y+3)/5.616 f_max; 'proportional' = "
                             "f_max min(1, x/cutoff_saturation), proportional to the total current; 'power' = "
                             "f_max min(1, (x/cutoff_saturation)^cutoff_exponent) [-]")
    lowpass_form: Literal["small_signal", "large_signal"] = Field(
        "small_signal", description="Form of Eq. 16's filter: 'small_signal' = the one-pole filter on L as printed; "
                                    "'large_signal' = the same filter (same cutoff, same gain) on exp(-L), the first-"
                                    "order logarithmic photoreceptor C dV/dt = I - I_0 e^V (Delbruck & Mead 1994): a "
                                    "falling step starts at the speed of the current the pixel carried [-]")
    cutoff_saturation: float = Field(275.0, gt=0, description="Normalised current at which the proportional or "
                                                              "power cutoff reaches its maximum (v2e: 255 + 20) [1]")
    cutoff_exponent: float = Field(0.5, gt=0, le=2, description="Exponent of the 'power' cutoff law (0.5: the "
                                                                "second-order photoreceptor, Graca & Delbruck 2021) [1]")
    # comparator (Eq. 17)
    threshold_on: float = Field(0.2, gt=0, description="Mean ON threshold theta_ON (in ln of current) [1]")
    threshold_off: float = Field(0.2, gt=0, description="Mean OFF threshold theta_OFF (in ln of current) [1]")
    threshold_sigma: float = Field(0.03, ge=0, description="Pixel-to-pixel standard deviation of the thresholds "
                                                           "(in ln of current) [1]")
    threshold_floor: float = Field(0.01, gt=0, description="Smallest threshold a pixel may draw (v2e: 0.01) "
                                                           "(in ln of current) [1]")
    threshold_redraw: bool = Field(False, description="Draw a new threshold of the fired polarity after every "
                                                      "event (IEBCS) instead of freezing it per pixel (paper, v2e) [-]")
    # noise (Eq. 18-20)
    leak_rate_hz: float = Field(0.1, ge=0, description="Junction-leak event rate R_leak of Eq. 18 [Hz]")
    parasitic_rate_per_lux_hz: float = Field(0.01, ge=0, description="Parasitic-photocurrent leak rate per unit "
                                                                     "pixel illuminance, f_para of Eq. 19 [Hz lx^-1]")
    luminous_efficacy_lm_per_W: float = Field(680.0, gt=0, description="Luminous efficacy eta of Eq. 19 "
                                                                       "(paper: 680 lm/W) [lm W^-1]")
    shot_noise_rate_hz: float = Field(0.1, ge=0, description="R_n of Eq. 20: shot-noise event rate of EACH "
                                                             "polarity in the dark (v2e's shot_noise_rate_hz is 2 R_n) [Hz]")
    shot_noise_intensity_factor: float = Field(0.25, ge=0, description="F of Eq. 20: shot-noise rate at I_max "
                                                                       "relative to the dark (v2e: 0.25) [1]")
    noise_rate_spread_decades: float = Field(0.0, ge=0, le=2, description="Pixel-to-pixel spread of the junction-"
                                             "leak and shot-noise rates (hot pixels): standard deviation of log10 of "
                                             "each pixel's rate factor, log-normal with mean 1 (v2e's "
                                             "noise_rate_cov_decades keeps the median at 1 instead) [decade]")
    log_current_max: float = Field(5.54, gt=0, description="I_max of Eq. 20: lin-log value of the brightest "
                                                           "current (paper: ln 255 = 5.54) [1]")
    timing_jitter_s: float = Field(0.0, ge=0, le=0.1, description="Timing jitter: each event's time stamp is "
                                   "delayed by sigma |z|, z standard normal (half-normal, mean 0.80 sigma) [s]")
    # reset (Eq. 21)
    refractory_period_s: float = Field(1e-4, ge=0, description="Refractory period T_refr of Eq. 21 [s]")

    @model_validator(mode="after")
    def _shot_probability_below_one(self):
        if 2.0 * self.shot_noise_rate_hz * max(1.0, self.shot_noise_intensity_factor) * self.time_step_s > 1.0:
            raise ValueError("2 shot_noise_rate_hz time_step_s (the shot-noise probability per step of Eq. 20) "
                             "exceeds 1; shorten time_step_s")
        if round(self.time_step_s * 1e9) < 1:
            raise ValueError("time_step_s must be at least 1 ns")
        return self

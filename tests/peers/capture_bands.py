"""Check /api/captures/{id}/bands against numpy on the capture's CSV export.

Usage: capture_bands.py CSV BANDS_JSON GAIN_WINDOW_S

- Spectra: per stand, a Welch PSD of the samples in the answer's `spectrum_span_s`
  (segments of the monitor's window, half overlapping, mean removed, periodic Hann,
  density scaling, one-sided) written here from numpy's rfft: same bins as the
  answer's, the same peak frequency, values within 1e-9 relative.
- Band signal: per stand and window end t, the RMS over the last GAIN_WINDOW_S before
  t of the samples band-passed by zeroing every FFT bin of the whole record outside
  the chatter band (a brick-wall filter, not the monitor's IIR band-pass): within 10%
  of the answer's wherever the numpy RMS is above the noise (0.02).

Prints one line per stand; exits non-zero with the first difference.
"""

import json
import sys

import numpy as np

def read_csv(path):
    """The export's header (the JSON file beside it), column names and samples."""
    with open(path[: -len(".csv")] + ".json") as f:
        header = json.load(f)
    with open(path) as f:
        names = f.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return header, names, data


def welch(x, fs, n):
    step = n - n // 2
    k = np.arange(n)
    w = 0.5 - 0.5 * np.cos(2 * np.pi * k / n)
    scale = 1.0 / (fs * np.sum(w * w))
    segments = [x[s:s + n] for s in range(0, len(x) - n + 1, step)]
    psd = np.mean([np.abs(np.fft.rfft((s - s.mean()) * w)) ** 2 * scale for s in segments], axis=0)
    psd[1:-1 if n % 2 == 0 else None] *= 2
    return psd


def main():
    csv_path, bands_path, gain_window_s = sys.argv[1], sys.argv[2], float(sys.argv[3])
    header, names, data = read_csv(csv_path)
    with open(bands_path) as f:
        bands = json.load(f)
    fs = bands["sample_rate_hz"]
    low, high = bands["chatter_band_hz"]
    failures = []
    for s, name in enumerate(bands["stands"]):
        x = data[:, names.index(name)]
        spectrum = bands["spectra"][s]
        step = spectrum["frequency_step_hz"]
        n = int(round(fs / step))
        a, b = (int(round(v * fs)) for v in bands["spectrum_span_s"])
        psd = welch(x[a:b], fs, n)
        api = np.array(spectrum["max"])
        freqs = np.array(spectrum["frequency_hz"])
        peak = np.argmax(psd) * fs / n
        if len(api) != len(psd) or not np.allclose(freqs, np.arange(len(psd)) * fs / n):
            failures.append(f"{name}: {len(api)} bins, numpy {len(psd)}")
        elif not np.allclose(api, psd, rtol=1e-9, atol=1e-15):
            worst = np.max(np.abs(api - psd) / np.maximum(psd, 1e-15))
            failures.append(f"{name}: PSD differs by up to {worst:.3g} relative")
        if spectrum["peak_hz"] != peak:
            failures.append(f"{name}: peak {spectrum['peak_hz']} Hz, numpy {peak} Hz")

        spectrum_all = np.fft.rfft(x - x.mean())
        f_all = np.fft.rfftfreq(len(x), 1 / fs)
        spectrum_all[(f_all < low) | (f_all > high)] = 0
        band = np.fft.irfft(spectrum_all, len(x))
        width = int(round(gain_window_s * fs))
        series = bands["band_rms"][s]
        worst = 0.0
        compared = 0
        for t, value in zip(series["t_s"], series["max"]):
            end = int(round(t * fs)) + 1
            if end < width:
                continue
            rms = float(np.sqrt(np.mean(band[end - width:end] ** 2)))
            if rms < 0.02:
                continue
            compared += 1
            worst = max(worst, abs(value / rms - 1))
        if compared < 10 or worst > 0.10:
            failures.append(f"{name}: band RMS off numpy's by up to {worst:.1%} over {compared} windows")
        print(f"{name}: PSD peak {peak:.1f} Hz (API {spectrum['peak_hz']} Hz), {len(psd)} bins; "
              f"band RMS within {worst:.2%} of numpy's brick-wall band over {compared} windows")
    if failures:
        print("\n".join(failures))
        sys.exit(1)


if __name__ == "__main__":
    main()

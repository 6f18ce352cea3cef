"""Bartlett's effective sample count of the acquisition window, on real motion and on noise.

Why docs/accuracy.md ("Parked") does not gate acquisition on a significance test:
this computes, for 6 s windows every 0.5 s (the estimator's defaults: 100 Hz grid,
2 Hz second-order Butterworth low-pass, lags +-0.5 s), the best |NCC| over the lags,
the window's effective sample count n_eff = N / (1 + 2 sum_m rho_x(m) rho_y(m)) from
the two signals' own autocorrelations (3 s of lags), and z = |NCC| sqrt(n_eff).

  cd /tmp && for s in 1 2 3; do vlsync-sim --family robot --seed $s --out r$s; done
  python3 bartlett_neff.py robot          # the robot family's motion
  python3 bartlett_neff.py noise 0        # white noise on both streams
  python3 bartlett_neff.py noise 1        # AR(1) noise, 1 s correlation time, on both

Needs numpy (pip install numpy). Not part of the test suite.
"""
import numpy as np, sys
fs=100.0
def biquad_lp(x, fc=2.0):
    k=np.tan(np.pi*fc/fs); q=1/np.sqrt(2); n=1/(1+k/q+k*k)
    b0=k*k*n; b=[b0,2*b0,b0]; a=[2*(k*k-1)*n,(1-k/q+k*k)*n]
    y=np.zeros_like(x); z0=z1=0.0
    for i,v in enumerate(x):
        o=b[0]*v+z0; z0=b[1]*v-a[0]*o+z1; z1=b[2]*v-a[1]*o; y[i]=o
    return y
def load(p):
    d=np.loadtxt(p,delimiter=',',skiprows=1,usecols=(0,1)); return d[:,0],d[:,1]
def grid(t,v,t0,t1):
    g=np.arange(t0,t1,1/fs); return g,np.interp(g,t,v)
def acf(x,M):
    x=x-x.mean(); n=len(x); c0=(x*x).sum()
    return np.array([(x[:n-m]*x[m:]).sum()/c0 for m in range(M+1)])
def stats(x,y,W=600,hop=50,L=50,M=300):
    out=[]
    for s in range(L, len(x)-W-L, hop):
        xw=x[s:s+W]
        best=0
        for m in range(-L,L+1):
            yw=y[s-m:s-m+W]
            r=np.corrcoef(xw,yw)[0,1]
            if abs(r)>abs(best): best=r
        ax=acf(xw,M); ay=acf(y[s:s+W],M)
        tau=1+2*(ax[1:]*ay[1:]).sum()
        neff=W/max(tau,1.0)
        out.append((abs(best),neff,abs(best)*np.sqrt(neff)))
    return np.array(out)
mode=sys.argv[1]
if mode=='robot':
    res=[]
    for s in (1,2,3):
        tc,vc=load(f'r{s}/cam.csv'); tl,vl=load(f'r{s}/lidar.csv')
        t0=max(tc[0],tl[0])+1; t1=min(tc[-1],tl[-1])-1
        _,c=grid(tc,vc,t0,t1); _,l=grid(tl,vl,t0,t1)
        res.append(stats(biquad_lp(l),biquad_lp(c)))
    r=np.vstack(res)
else:
    tau_c=float(sys.argv[2]); rng=np.random.default_rng(1); res=[]
    for rep in range(4):
        n=int(300*fs)
        def ar(tc):
            if tc<=0: return rng.standard_normal(n)
            phi=np.exp(-1/(fs*tc)); e=rng.standard_normal(n)*np.sqrt(1-phi*phi); x=np.zeros(n)
            for i in range(1,n): x[i]=phi*x[i-1]+e[i]
            return x
        res.append(stats(biquad_lp(ar(tau_c)),biquad_lp(ar(tau_c))))
    r=np.vstack(res)
q=lambda c,p: np.percentile(r[:,c],p)
print(mode, sys.argv[2:] , 'windows',len(r))
for name,c in (('score',0),('neff',1),('z',2)):
    print(f'  {name}: p1 {q(c,1):.2f} p10 {q(c,10):.2f} p50 {q(c,50):.2f} p90 {q(c,90):.2f} p99 {q(c,99):.2f} max {r[:,c].max():.2f}')
print('  score>=0.7:', (r[:,0]>=0.7).mean())

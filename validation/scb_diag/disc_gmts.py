"""Continuum prediction of the averaged-principal-stress criterion from the FE factors: the
Williams field (K_I, K_II, T only, per newton from data/reference/scb_fem.json) averaged over
discs of radius r_s (FFT convolution on a grid of r_s / 40), largest principal value over
centres within 1.2 r_s of the tip, P_c = beta K_Ic / sqrt(r_s) over it; printed against
Table 6.2 for several r_s. Usage: disc_gmts.py

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md)."""
import json, numpy as np
from scipy.signal import fftconvolve
from validation.cases.scb import _exp
from upscale.models.unified import williams_angular
fe=json.load(open('data/reference/scb_fem.json'))['rollers']
exP=np.array(_exp()['exp_P_c_kN'])
def field(KI,KII,T,X,Y):
    f=1/np.sqrt(2*np.pi*np.hypot(X,Y))
    fxx,fyy,fxy=williams_angular(KI,KII,np.arctan2(Y,X))
    return f*fxx+T,f*fyy,f*fxy
n=160; h=1.0/40   # units of r_s
g=(np.arange(-n,n)+0.5)*h
X,Y=np.meshgrid(g,g,indexing='ij')
k=int(1/h)+1; kg=np.arange(-k,k+1)*h; KX,KY=np.meshgrid(kg,kg,indexing='ij'); ker=(KX**2+KY**2<=1).astype(float); ker/=ker.sum()
def lmax(KI,KII,T, centre_r=1.2, mode='disc'):
    sxx,syy,sxy=field(KI,KII,T,X,Y)
    a=[fftconvolve(s,ker,mode='same') for s in (sxx,syy,sxy)]
    R=np.hypot(X,Y); m=R<=centre_r
    tr=(a[0]+a[1])/2; d=np.sqrt(((a[0]-a[1])/2)**2+a[2]**2)
    l=(tr+d)[m]
    i=np.argmax(l); return l[i], X[m][i], Y[m][i]
beta,xb,yb=lmax(1,0,0); print('beta',beta,xb,yb, 'tip-centred analytic 0.4063')
a=0.015; f=np.sqrt(np.pi*a)/(2*0.05*0.005)
for rs in [0.15e-3,0.5e-3,1e-3,2e-3,3e-3,5e-3]:
    P=[]
    for r in fe:
        KI,KII,T=r['Y_I']*f, r['Y_II']*f, r['T_star']/(2*0.05*0.005)
        # in units r_s=1: K scales as sqrt(rs): sigma = K/sqrt(rs) * unit ; T stays
        l,_,_=lmax(KI*1.0,KII*1.0,T*np.sqrt(rs))
        # sigma_bar per N = l/sqrt(rs); criterion beta*KIc/sqrt(rs)
        P.append(beta*2.13e6/l/1e3)
    P=np.array(P); e=100*(P/exP-1)
    print(rs*1e3,'mm',' '.join(f'{p:.2f}' for p in P),' err',' '.join(f'{x:+.0f}' for x in e),'mean %.1f max %.1f'%(np.abs(e).mean(),np.abs(e).max()))
